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

node -> launcher
    hello      {endpoint}                        bound its publisher; wants peers
    ready      {}                                set up, every subscriber connected
    heartbeat  {busy_secs, stats}                every ``HEARTBEAT_SECS``
    counts     {published, received, held}       lockstep: after each handled batch
                                                 (held: per port, waiting for release)
    wait_idle  {}                                lockstep: reply when the graph is idle
    stop_request {reason, exit_code}             a node asks the graph to stop (exit_code:
                                                 its verdict on the run, 0 = success)
    final      {stats}                           on a clean exit
launcher -> node
    connect    {endpoints: {node: endpoint}}     where each input's publisher is
    start      {}                                every node is ready: go
    idle       {}                                answer to wait_idle
    release    {}                                lockstep: handle the held messages
    busy       {}                                answer to wait_idle: not idle, but the
                                                 graph moved (the wait starts over)
    stop       {}                                stop cleanly now
launcher <-> launcher (one per host, ``runtime.hostlink``; CURVE-encrypted tcp)
    link_hello {host, run_secret, reply, graph, argv}  this run's link secret (the tag:
                                                 with it); reply=1: "yours is unknown here:
                                                 hello?"; graph: the digest of the graph and
                                                 its run mode (must be the same); argv: its
                                                 command line, to say which flags differ
    link_beat  {host, ready}                     every ``HEARTBEAT_SECS``; ready=1: its
                                                 nodes are ready (or running)
    link_ping  {host, t1} / link_pong {host, t1, t2, t3}   clock offset (NTP-style)
    link_stop  {host, reason, exit_code}         the graph stops
    link_counts {host, published, received, held}  lockstep: its nodes' newest counts,
                                                 sent when one changes (received and
                                                 held: "node/port")
    link_final {host, published}                 stopping: its nodes (but for listeners fed
                                                 from other hosts) have stopped, and
                                                 published this much in all, per topic
"""

from __future__ import annotations

import hashlib
import hmac
import math
import secrets
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import msgpack
import zmq

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
INPUT_COUNTERS = ("received", "dropped", "superseded", "bad_frames", "nonfinite")

_NUMBER = (int, float)
# The fields each kind must carry, and their types.
_FIELDS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "hello": {"endpoint": str},
    "ready": {},
    "heartbeat": {"busy_secs": _NUMBER, "stats": dict},
    "counts": {"published": dict, "received": dict, "held": dict},
    "wait_idle": {},
    "stop_request": {"reason": str, "exit_code": int},
    "final": {"stats": dict},
    "connect": {"endpoints": dict},
    "start": {},
    "idle": {},
    "busy": {},
    "release": {},
    "stop": {},
    # between the launchers of a graph's hosts (runtime.hostlink), over CURVE
    "link_hello": {"host": str, "run_secret": str, "reply": int, "graph": str, "argv": str},
    "link_beat": {"host": str, "ready": int},
    "link_ping": {"host": str, "t1": int},
    "link_pong": {"host": str, "t1": int, "t2": int, "t3": int},
    "link_stop": {"host": str, "reason": str, "exit_code": int},
    "link_counts": {"host": str, "published": dict, "received": dict, "held": dict},
    "link_final": {"host": str, "published": dict},
}


class ControlError(ValueError):
    """A control message that is malformed, of an unknown kind, or not signed by this run."""


def new_secret() -> bytes:
    """A fresh per-run secret."""
    return secrets.token_bytes(SECRET_BYTES)


def _tag(secret: bytes, payload: bytes) -> bytes:
    return hmac.new(secret, payload, hashlib.sha256).digest()[:TAG_BYTES]


def pack(secret: bytes, kind: str, **body: Any) -> list[bytes]:
    """One control message as its two frames, ``[payload, tag]``."""
    payload: bytes = msgpack.packb({"kind": kind, **body}, use_bin_type=True)
    return [payload, _tag(secret, payload)]


def unpack(secret: bytes, frames: Sequence[bytes], *, from_node: bool) -> dict[str, Any]:
    """Check and decode one control message (``from_node``: it must name its node).

    Raises:
        ControlError: wrong number of frames, a tag not made with ``secret``, a payload
            that is not a MessagePack map, an unknown kind, or a missing or ill-typed field.
    """
    if len(frames) != 2:
        raise ControlError(f"{len(frames)} frame(s), expected 2 (payload, tag)")
    payload, tag = frames
    if not hmac.compare_digest(_tag(secret, payload), tag):
        raise ControlError("tag does not match: not signed with this run's secret")
    try:
        msg = msgpack.unpackb(payload, raw=False)
    except (ValueError, msgpack.UnpackException) as err:
        raise ControlError(f"payload is not MessagePack: {err}") from err
    if not isinstance(msg, dict):
        raise ControlError(f"payload is a {type(msg).__name__}, expected a map")
    kind = msg.get("kind")
    fields = _FIELDS.get(kind) if isinstance(kind, str) else None
    if fields is None:
        raise ControlError(f"unknown kind {kind!r}")
    if from_node:
        fields = {**fields, "node": str}
    for name, kinds in fields.items():
        value = msg.get(name)
        if not isinstance(value, kinds) or isinstance(value, bool):
            raise ControlError(f"{kind}.{name}: expected {_names(kinds)}, got {value!r:.60}")
    if kind == "heartbeat" and not (math.isfinite(msg["busy_secs"]) and msg["busy_secs"] >= 0):
        raise ControlError(
            f"heartbeat.busy_secs: expected a finite number >= 0, got {msg['busy_secs']!r}"
        )
    if kind in ("stop_request", "link_stop") and not 0 <= msg["exit_code"] <= 255:
        raise ControlError(f"{kind}.exit_code: expected 0 to 255, got {msg['exit_code']!r}")
    if "stats" in msg:
        _check_stats(str(kind), msg["stats"])
    for name in ("published", "received", "held", "endpoints"):
        value = msg.get(name, {})
        check = _count if name != "endpoints" else (lambda v: isinstance(v, str))
        if not all(isinstance(k, str) and check(v) for k, v in value.items()):
            raise ControlError(f"{kind}.{name}: expected a map of names to values")
    return msg


def _names(kinds: type | tuple[type, ...]) -> str:
    return " or ".join(k.__name__ for k in (kinds if isinstance(kinds, tuple) else (kinds,)))


def _check_stats(kind: str, stats: dict[str, Any]) -> None:
    """A node's counters: ``{published: {topic: n}, inputs: {port: {topic, counters}}}``."""
    published = stats.get("published", {})
    inputs = stats.get("inputs", {})
    ok = isinstance(published, dict) and isinstance(inputs, dict)
    ok = ok and all(isinstance(t, str) and _count(n) for t, n in published.items())
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

    def send(self, rid: bytes | None, kind: str, **body: Any) -> None:
        """Send to the peer ``rid`` (nothing if None: the node has not said hello yet)."""
        if rid is None:
            return
        try:
            self.socket.send_multipart([rid, *pack(self.secret, kind, **body)])
        except zmq.ZMQError:
            pass  # the node is gone; the launcher sees its exit

    def refuse(self, why: str) -> None:
        """Count and log a message that failed the checks; never fatal."""
        self.refused += 1
        if self.refused <= REFUSED_LOG_FIRST or self.refused % REFUSED_LOG_EVERY == 0:
            self.say(f"control: refused message #{self.refused}: {why}")

    def receive(self, timeout_ms: int) -> Iterator[tuple[bytes, dict[str, Any]]]:
        """``(rid, message)`` for every valid message waiting (after ``timeout_ms`` at most)."""
        if not self.socket.poll(timeout_ms):
            return
        while True:
            try:
                frames = self.socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                yield frames[0], unpack(self.secret, frames[1:], from_node=True)
            except ControlError as err:
                self.refuse(str(err))

    def close(self) -> None:
        self.socket.close(linger=0)
