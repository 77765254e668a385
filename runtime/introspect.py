"""Looking into a running graph without touching it: a tap on one topic, and its rate.

A :class:`Tap` is one more ZeroMQ subscriber on a topic's publisher (found in the run's
``status.json``, :mod:`runtime.status`): read-only, and it cannot slow the graph. The
publisher sends each message once per subscriber without waiting for any (its high-water
mark drops what a slow tap does not take), and the arrays travel as zero-copy frames.
The tap subscribes to the topic's name less its last character, so the publisher does not
count it among the subscribers it waits for at (re)start; frames of other topics that
share the prefix are dropped here.

Taking every message still costs the machine a copy of each (and, for ``echo``, its
decoding and summaries) in the tap's process: three taps on a 2-core machine took 60%
of a camera graph's throughput (``bench.introspection``). :meth:`Tap.sample` takes one
message and unsubscribes until the next is wanted, so between samples the publisher
sends the tap nothing at all: ``topic echo`` samples at 10 Hz unless told ``--every``.

:class:`Rate` is ``topic hz``'s arithmetic: the arrival rate over a sliding window of
periods, with their min, max and standard deviation; for messages with a header, also
the rate their stamps say (the publisher's own clock: what the tap's arrival times add,
on a loaded machine, is the delivery's jitter) and the first and last seq it measured.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import msgspec
import numpy as np
import zmq

from messages.base import Message
from messages.codec import decode
from runtime.zmqio import recv_parts

TAP_HWM = 1000  # messages a tap may fall behind before the publisher drops its copies


class Tap:
    """A read-only subscriber to ``topic`` at ``endpoint`` (close it, or use ``with``)."""

    def __init__(self, endpoint: str, topic: str, *, others: Iterable[str] = ()) -> None:
        self.topic = topic
        self.name = topic.encode()
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, TAP_HWM)
        self.sock.setsockopt(zmq.LINGER, 0)
        prefix = self.name[:-1]
        if prefix.decode(errors="replace") in set(others) or not prefix:
            prefix = self.name  # another topic is named so: the exact name after all
        self.prefix = prefix
        self.subscribed = False
        self.sock.connect(endpoint)

    def subscribe(self) -> None:
        if not self.subscribed:
            self.sock.setsockopt(zmq.SUBSCRIBE, self.prefix)
            self.subscribed = True

    def sample(self, timeout_secs: float) -> list[Any] | None:
        """One fresh message (subscribe, take it, unsubscribe), or None after the timeout;
        what arrived since the last sample is dropped unread."""
        while recv_parts(self.sock) is not None:
            pass
        self.subscribe()
        try:
            return self.receive(timeout_secs)
        finally:
            self.sock.setsockopt(zmq.UNSUBSCRIBE, self.prefix)
            self.subscribed = False

    def receive(self, timeout_secs: float) -> list[Any] | None:
        """The next message's frames on this topic (every one, in order, from the first
        call on), or None after ``timeout_secs``."""
        self.subscribe()
        end = time.monotonic() + timeout_secs
        while True:
            frames = recv_parts(self.sock)
            if frames is not None:
                if frames[0].bytes == self.name:
                    return frames
                continue
            left = end - time.monotonic()
            if left <= 0 or not self.sock.poll(max(1, int(left * 1000))):
                return None

    def close(self) -> None:
        self.sock.close()
        self.ctx.term()

    def __enter__(self) -> Tap:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def decode_message(frames: list[Any]) -> Message:
    """A tapped message decoded with today's classes."""
    return decode(frames)[1]


def plain_fields(msg: Message) -> dict[str, Any]:
    """A message's fields as ``bag echo`` prints them: nested structs as dicts, arrays kept."""

    def plain(value: Any) -> Any:
        if isinstance(value, msgspec.Struct):
            return {f: plain(getattr(value, f)) for f in value.__struct_fields__}
        if isinstance(value, list | tuple):
            return [plain(v) for v in value]
        return value

    return {f: plain(getattr(msg, f)) for f in msg.__struct_fields__}


@dataclass
class Rate:
    """Arrival times of one topic: the rate and the spread of periods over ``window``."""

    window: int = 1000
    arrivals: deque[float] = field(default_factory=deque)
    # (stamp_nanos, seq) of each arrival in the window; None for a message without a header.
    headers: deque[tuple[int, int] | None] = field(default_factory=deque)
    count: int = 0

    def add(self, when_secs: float, header: tuple[int, int] | None = None) -> None:
        """One arrival at ``when_secs``; ``header``: its ``(stamp_nanos, seq)``."""
        self.arrivals.append(when_secs)
        self.headers.append(header)
        self.count += 1
        while len(self.arrivals) > self.window + 1:
            self.arrivals.popleft()
            self.headers.popleft()

    def summary(self) -> dict[str, float] | None:
        """``rate_hz``, ``min_secs``, ``max_secs``, ``std_secs`` and ``periods``; None
        before two arrivals. When the first and last message of the window have headers,
        ``stamp_rate_hz`` (the periods over their stamps' span), ``first_seq`` and
        ``last_seq``."""
        if len(self.arrivals) < 2:
            return None
        periods = np.diff(np.asarray(self.arrivals))
        span = float(self.arrivals[-1] - self.arrivals[0])
        out = {
            "rate_hz": len(periods) / span if span > 0 else float("inf"),
            "min_secs": float(periods.min()),
            "max_secs": float(periods.max()),
            "std_secs": float(periods.std()),
            "periods": float(len(periods)),
        }
        first, last = self.headers[0], self.headers[-1]
        if first is not None and last is not None:
            stamps_secs = (last[0] - first[0]) / 1e9
            out["stamp_rate_hz"] = len(periods) / stamps_secs if stamps_secs > 0 else float("inf")
            out["first_seq"], out["last_seq"] = float(first[1]), float(last[1])
        return out
