"""A fake IO: feed messages to a node and collect what it publishes, without sockets."""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from messages.base import Message
from messages.codec import decode, encode
from runtime.node import Node
from runtime.params import build_params, timer_period_nanos


@dataclass
class _Timer:
    period_nanos: int
    callback: Callable[[], None]
    due_nanos: int


class FakeIO:
    """Records published messages per output; the clock moves only when told.

    Every published message goes through the real codec and back, so a node that
    publishes something the wire cannot carry fails its tests.
    """

    def __init__(self, name: str = "test", now_nanos: int = 0) -> None:
        self.log = logging.getLogger(name)
        self.published: dict[str, list[Message]] = defaultdict(list)
        # Per output or topic: published with a NaN or infinity where the type says
        # finite, as the real IO counts them.
        self.nonfinite: dict[str, int] = defaultdict(int)
        self.stop_reason: str | None = None
        self.stop_exit_code = 0
        self.stop_requested = False
        self._now = now_nanos
        self._timers: list[_Timer] = []
        self._seq: dict[str, int] = defaultdict(int)
        self.outputs: Mapping[str, type[Message]] = {}
        self.dropped: dict[str, int] = {}

    def publish(self, output: str, msg: Message) -> None:
        if output not in self.outputs:
            raise KeyError(f"{output!r} is not a declared output: {sorted(self.outputs)}")
        if not isinstance(msg, self.outputs[output]):
            raise TypeError(
                f"{output}: expected {self.outputs[output].__name__}, got {type(msg).__name__}"
            )
        header = getattr(msg, "header", None)
        if header is not None:
            header.seq = self._seq[output]
        self._seq[output] += 1
        _, copy = decode(encode(output, msg))
        self.published[output].append(copy)
        self._count_nonfinite(output, msg)

    def publish_raw(self, topic: str, frames: list[Any], decoded: Message | None = None) -> None:
        """Record raw frames (decoded, so tests see messages) under their topic."""
        topics = {out if "/" in out else f"{self.log.name}/{out}" for out in self.outputs}
        if topic not in topics:
            raise KeyError(f"{topic!r} is not one of the output topics {sorted(topics)}")
        _, msg = decode([topic.encode(), *frames[1:]])
        self.published[topic].append(msg)
        if decoded is not None:
            self._count_nonfinite(topic, decoded)

    def _count_nonfinite(self, key: str, msg: Message) -> None:
        if msg.finite_fields and msg.nonfinite_fields():
            self.nonfinite[key] += 1

    def wait_idle(self, timeout_secs: float, *, last: bool = False) -> bool:
        return True

    def lockstep_barrier(self, topic: str) -> bool:
        return True  # no graph to reason about: always the safe answer

    def drops(self) -> dict[str, int]:
        return dict(self.dropped)

    def add_timer(self, period_secs: float, callback: Callable[[], None]) -> None:
        period = timer_period_nanos(period_secs)
        self._timers.append(_Timer(period, callback, self._now + period))

    def cancel_timer(self, callback: Callable[[], None]) -> None:
        self._timers = [t for t in self._timers if t.callback != callback]

    def now_nanos(self) -> int:
        return self._now

    def request_stop(self, reason: str, *, exit_code: int = 0) -> None:
        self.stop_reason = reason
        self.stop_exit_code = exit_code

    def advance(self, secs: float) -> None:
        """Move the clock forward, firing every timer that falls due, in time order."""
        end = self._now + int(secs * 1e9)
        while self._timers and self.stop_reason is None:
            timer = min(self._timers, key=lambda t: t.due_nanos)
            if timer.due_nanos > end:
                break
            self._now = timer.due_nanos
            timer.due_nanos += timer.period_nanos
            timer.callback()
        self._now = max(self._now, end)


def make_node(
    cls: type[Node],
    params: Mapping[str, Any] | None = None,
    *,
    name: str = "test",
    now_nanos: int = 0,
) -> tuple[Any, FakeIO]:
    """Construct and set up ``cls`` with a :class:`FakeIO`; returns ``(node, io)``."""
    io = FakeIO(name, now_nanos)
    built = build_params(cls.Params, params)
    io.outputs = cls.ports(built)[1]
    node = cls(name, built, io)
    node.setup()
    return node, io


def feed(node: Node, port: str, msg: Message) -> None:
    """Deliver ``msg`` to ``port`` the way the runtime would (through the codec)."""
    expected = type(node).inputs[port]
    _, copy = decode(encode(port, msg), expect=expected)
    node.handle(port, copy)
