"""A node's IO in a live graph: its publisher, control socket, inputs and timers.

The node binds one XPUB (verbose, so it sees every subscription) and publishes the
codec's multipart frames on it without copying the arrays; control messages to and
from the launcher are signed with the run's secret (``runtime.protocol``). The loop
that reads inputs and runs timers is :class:`runtime.runner.Runner`'s.
"""

from __future__ import annotations

import logging
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zmq

from messages.base import Message
from messages.codec import encode
from messages.control import Busy, Control, Counts, FromNode, Idle, Stop, StopRequest, WaitIdle
from runtime import protocol
from runtime.counters import InputCounters
from runtime.ordering import StampOrder
from runtime.params import timer_period_nanos
from runtime.protocol import ControlError
from runtime.security import Guard, KeyPair, needs_curve, serve

# Plain ints: pyzmq 27's flags are enum members, and arithmetic on them costs about a
# microsecond per part of a message.
_SNDMORE = int(zmq.SNDMORE)
_POLLIN = int(zmq.POLLIN)
_NOBLOCK = int(zmq.NOBLOCK)
# How often a node waiting at a lockstep barrier looks at stop_requested.
STOP_POLL_SECS = 0.1


# pyzmq's compiled send, under the Python layer of ``zmq.Socket.send`` (which adds only
# ``routing_id`` and ``group``, for draft sockets): 0.45 us less per part. Its compiled
# ``get``, with a plain-int option, for the question recv_parts asks of every message.
# Both send and recv are called with positional arguments: a keyword argument to a
# compiled method is parsed on a slower path (0.8 us less for five parts sent and read).
_send = zmq.backend.Socket.send
_recv = zmq.backend.Socket.recv
_get = zmq.backend.Socket.get
_EVENTS = int(zmq.EVENTS)


def send_parts(sock: zmq.Socket[Any], parts: Sequence[Any]) -> None:
    """Send ``parts`` as one multipart message, arrays without copying.

    The same frames as ``send_multipart(parts, copy=False)`` at about 8 us less per
    message of five parts: no flag arithmetic on enum members per part, and pyzmq's
    compiled send called directly (see docs/transport.md).
    """
    for part in parts[:-1]:
        _send(sock, part, _SNDMORE, False)  # (data, flags, copy)
    _send(sock, parts[-1], 0, False)


def recv_parts(sock: zmq.Socket[Any], *, waiting: bool = False) -> list[zmq.Frame] | None:
    """The next whole multipart message as zero-copy frames, or None if none is waiting.

    Asks the socket whether a message waits rather than catching ``zmq.Again`` (a raised
    error costs 3.8 us, the question 1.4), and follows each frame's ``more`` flag rather
    than ``recv_multipart``'s ``getsockopt(RCVMORE)`` per part. The parts of a message
    arrive together, so the reads after the first never block.

    ``waiting``: the caller knows a message waits (a poll has just said so and nothing
    was read since), so the question is not asked: most of its cost is pyzmq turning the
    option into an enum member. The first read is non-blocking either way, and a socket
    that has nothing after all answers None.
    """
    if not waiting and not _get(sock, _EVENTS) & _POLLIN:  # type: ignore[operator]
        return None
    try:
        frame = _recv(sock, _NOBLOCK, False)  # (flags, copy)
    except zmq.Again:
        return None
    frames = [frame]
    while frame.more:
        frame = _recv(sock, 0, False)
        frames.append(frame)
    return frames


@dataclass
class Input:
    port: str
    topic: str
    policy: str
    kind: type[Message] | None
    counters: InputCounters = field(default_factory=InputCounters)


@dataclass
class Source:
    """One SUB socket and the inputs it feeds, by exact topic (SUB filters by prefix)."""

    socket: zmq.Socket[Any]
    inputs: dict[bytes, list[Input]] = field(default_factory=dict)
    latest: bool = False  # only a socket of one ``latest`` input, outside lockstep


@dataclass(frozen=True, slots=True)
class _Output:
    """One declared output as :meth:`ZmqIO.publish` needs it, prepared at its first message:
    its topic, declared type, whether a lockstep source must tell its counts before each
    message on it (``ZmqIO._count_ahead``), and the finite check of its type."""

    topic: str
    kind: type[Message] | None
    barrier: bool
    finite_check: Callable[[Message], bool] | None


@dataclass(eq=False)  # by identity: the runner asks whether a timer is still there
class Timer:
    period_nanos: int
    callback: Callable[[], None]
    due_nanos: int


class ZmqIO:
    """The node's IO in a live graph (see :class:`runtime.node.IO`)."""

    def __init__(self, spec: dict[str, Any], ctx: zmq.Context[Any]) -> None:
        self.spec = spec
        self.name: str = spec["name"]
        self.log = logging.getLogger(self.name)
        self.ctx = ctx
        self.topics: dict[str, str] = spec["outputs"]
        self.output_types: dict[str, type[Message] | None] = {}
        self.pub = ctx.socket(zmq.XPUB)
        self.pub.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.lockstep: bool = spec.get("lockstep", False)
        # Lockstep must not lose a message to a high-water mark: the replay bounds the flow.
        self.pub.setsockopt(zmq.SNDHWM, 0 if self.lockstep else spec.get("sndhwm", 1000))
        self.pub.setsockopt(zmq.LINGER, 1000)
        curve: dict[str, Any] = spec.get("curve") or {}
        self.keys = KeyPair(curve["public"], curve["secret"]) if curve else None
        self.guard: Guard | None = None
        if self.keys is not None and needs_curve(spec["bind"]):
            # ZAP before the bind: a CURVE socket with no handler would admit any key.
            self.guard = Guard(ctx, curve["authorized"], self.log.warning)
            serve(self.pub, self.keys)
            self.guard.watch(self.pub)
            self.guard.start()
        self.endpoint = self._bind(spec["bind"])
        self.secret = bytes.fromhex(spec["secret"])
        self.control = ctx.socket(zmq.DEALER)
        self.control.setsockopt(zmq.LINGER, 1000)
        self.control.connect(spec["control"])
        self.inputs: list[Input] = []
        self.published: dict[str, int] = defaultdict(int)
        self.nonfinite: dict[str, int] = defaultdict(int)  # per topic, see _count_nonfinite
        self._outputs: dict[str, _Output] = {}
        self.timers: list[Timer] = []
        self.stop_requested = False
        self.waiting = False  # in wait_idle
        # Lockstep, an ordered fan-in: what it received and has not handled yet, in order.
        self.held: list[tuple[Input, Message]] = []
        self.order: StampOrder | None = None  # the runner's, for the counts it reports
        self.barrier_topics = frozenset(spec.get("barrier_topics", ()))
        self.source_in_lockstep = self.lockstep and not spec.get("inputs")
        self.subscriptions: dict[bytes, int] = defaultdict(int)

    def _bind(self, endpoint: str) -> str:
        self.pub.bind(endpoint)
        endpoint = self.pub.getsockopt(zmq.LAST_ENDPOINT)
        assert isinstance(endpoint, bytes)
        return endpoint.decode()

    # -- the IO protocol -------------------------------------------------------
    def publish(self, output: str, msg: Message) -> None:
        # Every lookup that does not depend on the message is made once per output (see
        # _Output): this runs for every message a node sends (docs/transport.md).
        out = self._outputs.get(output) or self._output(output)
        kind = out.kind
        if kind is not None and type(msg) is not kind and not isinstance(msg, kind):
            raise TypeError(
                f"{self.name}.{output}: expected {kind.__name__}, got {type(msg).__name__}"
            )
        topic = out.topic
        published = self.published
        header = getattr(msg, "header", None)
        if header is not None:
            header.seq = published[topic]
        frames = encode(topic, msg)
        published[topic] += 1
        if out.barrier:
            self.send_counts()  # see _count_ahead
        send_parts(self.pub, frames)
        # After the send: not on the frame's way out. The check of the output's own class
        # is prepared; a subclass's is looked up (it may declare other finite fields).
        check = out.finite_check if type(msg) is kind else type(msg).finite_check()
        if check is not None and not check(msg):
            self._count_nonfinite(topic, msg)

    def _output(self, output: str) -> _Output:
        """Prepare ``output`` at its first message (raises ``KeyError`` if undeclared)."""
        topic = self.topics.get(output)
        if topic is None:
            raise KeyError(
                f"{self.name}: {output!r} is not a declared output: {sorted(self.topics)}"
            )
        kind = self.output_types.get(output)
        barrier = self.source_in_lockstep and topic in self.barrier_topics
        check = kind.finite_check() if kind is not None else None
        prepared = self._outputs[output] = _Output(topic, kind, barrier, check)
        return prepared

    def publish_raw(self, topic: str, frames: list[Any], decoded: Message | None = None) -> None:
        if topic not in self.topics.values():
            raise KeyError(f"{self.name}: {topic!r} is not one of its output topics")
        self._count_ahead(topic)
        send_parts(self.pub, [topic.encode(), *frames[1:]])
        if decoded is not None and (check := type(decoded).finite_check()) is not None:
            if not check(decoded):
                self._count_nonfinite(topic, decoded)

    def _count_nonfinite(self, topic: str, msg: Message) -> None:
        """Count (per topic) and warn once about a message whose ``finite_fields`` are not
        (its class's finite check said no; the fields are named here, and a message whose
        numbers only overflowed their sum has none to name and is not counted).

        Checked once, where the message is published, while its arrays are in this
        process's caches: not again by each subscriber, which would read every pixel of
        every frame once per reader (docs/runtime.md, "Values that must be finite")."""
        if bad := msg.nonfinite_fields():
            self.nonfinite[topic] += 1
            if self.nonfinite[topic] == 1:
                self.log.warning(
                    "%s: non-finite %s in a %s; such messages are counted (the "
                    "'nonfinite' column at the end), this is the only warning",
                    topic,
                    ", ".join(bad),
                    type(msg).__name__,
                )

    def _count_ahead(self, topic: str) -> None:
        """Count a message about to go out. A source (the replay) tells the launcher first
        when the topic can reach an ordered fan-in (a barrier topic): having no inputs, its
        counts are the only sign of the message, and a receiver's count arriving first
        would make the edge look delivered and the fan-ins be released too early."""
        self.published[topic] += 1
        if self.source_in_lockstep and topic in self.barrier_topics:
            self.send_counts()

    def add_timer(self, period_secs: float, callback: Callable[[], None]) -> None:
        try:
            period = timer_period_nanos(period_secs)
        except ValueError as err:
            raise ValueError(f"{self.name}: {err}") from err
        self.timers.append(Timer(period, callback, time.monotonic_ns() + period))

    def cancel_timer(self, callback: Callable[[], None]) -> None:
        # A new list: the runner may be iterating over the old one (it checks membership).
        self.timers = [t for t in self.timers if t.callback != callback]

    def now_nanos(self) -> int:
        return time.time_ns()

    def request_stop(self, reason: str, *, exit_code: int = 0) -> None:
        self.tell(StopRequest, reason=reason, exit_code=exit_code)

    def tell(
        self, kind: type[FromNode], sock: zmq.Socket[Any] | None = None, **fields: Any
    ) -> None:
        """Send one signed control message of ``kind``, from this node, to the launcher (on
        ``sock``, else the main one)."""
        frames = protocol.pack(self.secret, kind(node=self.name, **fields))
        (sock or self.control).send_multipart(frames)

    def hear(self) -> Control | None:
        """The next control message from the launcher; None (logged) if it fails the checks."""
        frames = self.control.recv_multipart()
        try:
            return protocol.unpack(self.secret, frames, from_node=False)
        except ControlError as err:
            self.log.warning("refused a control message: %s", err)
            return None

    def wait_idle(self, timeout_secs: float, *, last: bool = False) -> bool:
        if not self.lockstep:
            return True
        self.send_counts()
        self.tell(WaitIdle, last=int(last))
        self.waiting = True  # not busy in a handler: waiting for others (the heartbeat)
        try:
            deadline = time.monotonic() + timeout_secs
            while (left := deadline - time.monotonic()) > 0:
                # In slices: a signal (SIGTERM, the launcher's death) only sets
                # stop_requested, and a poll of the whole timeout would sleep through it.
                if self.stop_requested:
                    return False
                if not self.control.poll(int(min(left, STOP_POLL_SECS) * 1000) + 1):
                    continue
                msg = self.hear()
                if msg is None:
                    continue
                if isinstance(msg, Idle):
                    return True
                if isinstance(msg, Busy):  # slow, not stuck: the timeout starts over
                    deadline = time.monotonic() + timeout_secs
                if isinstance(msg, Stop):
                    self.stop_requested = True
                    return False
            return False
        finally:
            self.waiting = False

    def lockstep_barrier(self, topic: str) -> bool:
        return self.lockstep and topic in self.barrier_topics

    def drops(self) -> dict[str, int]:
        return {i.topic: i.counters.dropped + i.counters.superseded for i in self.inputs}

    # -- used by the runner ----------------------------------------------------
    def stats(self) -> dict[str, Any]:
        return {
            "published": dict(self.published),
            "nonfinite": dict(self.nonfinite),
            "inputs": {
                i.port: {
                    "topic": i.topic,
                    "received": i.counters.received,
                    "dropped": i.counters.gaps(),
                    "superseded": i.counters.superseded,
                    "bad_frames": i.counters.bad_frames,
                }
                for i in self.inputs
            },
            "cpu_secs": time.process_time(),
        }

    def send_counts(self) -> None:
        self.tell(
            Counts,
            published=dict(self.published),
            received={i.port: i.counters.received for i in self.inputs},
            held=dict(Counter(inp.port for inp, _ in self.held)),
            pending=self.order.pending() if self.order is not None else {},
        )
