"""The control protocol between the launcher and its node processes.

Every node process has a DEALER socket connected to the launcher's ROUTER; a second
DEALER is owned by the node's heartbeat thread. A control message is two frames,
``[payload, tag]``: the payload is one MessagePack map with a ``kind`` and, from a
node, the sending ``node``'s name; the tag is the first 16 bytes of
HMAC-SHA256(run secret, payload). The launcher makes a fresh 32-byte secret per run and
hands it to each child on its stdin pipe with the rest of its spec (never on a command
line or in the environment, which other processes of the user can read). Both sides
check the tag and every field of every message; :func:`unpack` raises
:class:`ControlError` for anything else, which the receiver counts, logs and drops.

The messages themselves, one typed struct per ``kind``, are declared in
:mod:`messages.control` (with the table of who sends which).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import msgspec
import zmq

from messages.control import KINDS, Control, Final, FromNode, Heartbeat

HEARTBEAT_SECS = 0.5
# The largest control message a launcher takes (ZMQ_MAXMSGSIZE, per frame): a heartbeat of a
# node with a thousand inputs is about 100 kB. ZeroMQ reads a frame's length first and drops
# the connection of a peer that announces more, before anything is allocated for it.
MAX_CONTROL_BYTES = 1 << 20
REFUSED_LOG_FIRST = 10  # a refused message is logged for the first ten, then every 100th
REFUSED_LOG_EVERY = 100
SECRET_BYTES = 32
TAG_BYTES = 16
# Counters of one input in a node's stats (see ``runtime.runner.InputCounters``).
INPUT_COUNTERS = ("received", "dropped", "superseded", "bad_frames")

_encoder = msgspec.msgpack.Encoder()


class ControlError(ValueError):
    """A control message that is malformed, of an unknown kind, or not signed by this run."""


def new_secret() -> bytes:
    """A fresh per-run secret."""
    return secrets.token_bytes(SECRET_BYTES)


def _tag(secret: bytes, payload: bytes) -> bytes:
    return hmac.new(secret, payload, hashlib.sha256).digest()[:TAG_BYTES]


def pack(secret: bytes, msg: Control) -> list[bytes]:
    """One control message as its two frames, ``[payload, tag]``."""
    payload = _encoder.encode(msg)
    return [payload, _tag(secret, payload)]


def unpack(secret: bytes, frames: Sequence[bytes], *, from_node: bool) -> Control:
    """Check and decode one control message (``from_node``: it must be a node's, naming it).

    Raises:
        ControlError: wrong number of frames, a tag not made with ``secret``, a payload
            that is not a MessagePack map, an unknown kind, or a field that is missing,
            unknown, of the wrong type or out of its limits (the error names it).
    """
    if len(frames) != 2:
        raise ControlError(f"{len(frames)} frame(s), expected 2 (payload, tag)")
    payload, tag = frames
    if not hmac.compare_digest(_tag(secret, payload), tag):
        raise ControlError("tag does not match: not signed with this run's secret")
    try:
        body = msgspec.msgpack.decode(payload)
    except msgspec.DecodeError as err:
        raise ControlError(f"payload is not MessagePack: {err}") from err
    if not isinstance(body, dict):
        raise ControlError(f"payload is a {type(body).__name__}, expected a map")
    kind = body.get("kind")
    cls = KINDS.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ControlError(f"unknown kind {kind!r:.40}")
    if from_node and not issubclass(cls, FromNode):
        raise ControlError(f"{kind}: not a message a node sends")
    try:
        msg = msgspec.convert(body, cls)
    except msgspec.ValidationError as err:
        raise ControlError(f"{kind}: {err}") from err
    if isinstance(msg, Heartbeat | Final):
        _check_stats(str(kind), msg.stats)
    return msg


def _check_stats(kind: str, stats: dict[str, Any]) -> None:
    """A node's counters: ``{published: {topic: n}, nonfinite: {topic: n},
    inputs: {port: {topic, counters}}}``."""
    per_topic = [stats.get("published", {}), stats.get("nonfinite", {})]
    inputs = stats.get("inputs", {})
    ok = all(isinstance(counts, dict) for counts in per_topic) and isinstance(inputs, dict)
    ok = ok and all(
        isinstance(t, str) and _count(n) for counts in per_topic for t, n in counts.items()
    )
    ok = ok and all(
        isinstance(port, str)
        and isinstance(row, dict)
        and isinstance(row.get("topic"), str)
        and all(_count(row.get(key)) for key in INPUT_COUNTERS)
        for port, row in inputs.items()
    )
    if not ok:
        raise ControlError(f"{kind}.stats: not a node's counters")


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


class ControlServer:
    """The launcher's end: a ROUTER that signs what it sends and checks what it hears.

    A node is known by the name in its signed messages, never by its socket identity
    (which any peer may choose); replies go to the ROUTER id a message came from.
    """

    def __init__(
        self, ctx: zmq.Context[Any], endpoint: str, secret: bytes, say: Callable[[str], None]
    ) -> None:
        self.secret = secret
        self.say = say
        self.refused = 0
        self.socket = ctx.socket(zmq.ROUTER)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.ROUTER_MANDATORY, 1)
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_CONTROL_BYTES)
        self.socket.bind(endpoint)

    def send(self, rid: bytes | None, msg: Control) -> None:
        """Send to the peer ``rid`` (nothing if None: the node has not said hello yet)."""
        if rid is None:
            return
        try:
            self.socket.send_multipart([rid, *pack(self.secret, msg)])
        except zmq.ZMQError:
            pass  # the node is gone; the launcher sees its exit

    def refuse(self, why: str) -> None:
        """Count and log a message that failed the checks; never fatal."""
        self.refused += 1
        if self.refused <= REFUSED_LOG_FIRST or self.refused % REFUSED_LOG_EVERY == 0:
            self.say(f"control: refused message #{self.refused}: {why}")

    def receive(self, timeout_ms: int) -> Iterator[tuple[bytes, FromNode]]:
        """``(rid, message)`` for every valid message waiting (after ``timeout_ms`` at most)."""
        if not self.socket.poll(timeout_ms):
            return
        while True:
            try:
                frames = self.socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                msg = unpack(self.secret, frames[1:], from_node=True)
                assert isinstance(msg, FromNode)  # unpack refuses any other from a node
                yield frames[0], msg
            except ControlError as err:
                self.refuse(str(err))

    def close(self) -> None:
        self.socket.close(linger=0)
