"""Control messages: between the launcher and its node processes, and between the launchers
of a graph's hosts. Declared once, as typed messages; ``runtime.protocol`` signs, sends
and checks them.

Each is one MessagePack map whose ``kind`` names its type (the struct's tag), then its
fields; decoding checks every field's type and limits and refuses any other key, so a
receiver holds a typed message or nothing. ``stats`` (a node's counters) is a map whose
shape ``runtime.protocol`` checks (the counters it holds grow with the runtime).

node -> launcher
    hello      {endpoint}                        bound its publisher; wants peers
    ready      {}                                set up, every subscriber connected
    heartbeat  {busy_secs, stats}                every ``HEARTBEAT_SECS``
    counts     {published, received, held, pending}  lockstep: after each handled batch
                                                 (held: per port, waiting for release;
                                                 pending: per port, waiting for its other
                                                 ordered inputs, ``runtime.ordering``)
    wait_idle  {last}                            lockstep: reply when the graph is idle
                                                 (last=1: the source has sent its last
                                                 message, so nothing pending may wait)
    stop_request {reason, exit_code}             a node asks the graph to stop (exit_code:
                                                 its verdict on the run, 0 = success)
    final      {stats}                           on a clean exit
launcher -> node
    connect    {endpoints: {node: endpoint}}     where each input's publisher is
    start      {}                                every node is ready: go
    idle       {}                                answer to wait_idle
    release    {pending}                         lockstep: handle the held messages
                                                 (pending=1: and the pending ones)
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
    link_counts {host, published, received, held, pending, last}  lockstep: its nodes'
                                                 newest counts, sent when one changes
                                                 (received, held and pending: "node/port";
                                                 last=1: its replay sent its last message)
    link_final {host, published}                 stopping: its nodes (but for listeners fed
                                                 from other hosts) have stopped, and
                                                 published this much in all, per topic
"""

from __future__ import annotations

from typing import Annotated, Any

import msgspec

Count = Annotated[int, msgspec.Meta(ge=0)]
ExitCode = Annotated[int, msgspec.Meta(ge=0, le=255)]
Flag = Annotated[int, msgspec.Meta(ge=0, le=1)]
# A finite duration: NaN fails the lower bound, infinity the upper one.
Seconds = Annotated[float, msgspec.Meta(ge=0.0, le=1e9)]


class Control(msgspec.Struct, tag_field="kind", forbid_unknown_fields=True, kw_only=True):
    """A control message; its ``kind`` on the wire is the subclass's tag."""


class FromNode(Control):
    """A node's message to the launcher: it names the node (the signature vouches for it)."""

    node: str


class Hello(FromNode, tag="hello"):
    endpoint: str


class Ready(FromNode, tag="ready"):
    pass


class Heartbeat(FromNode, tag="heartbeat"):
    busy_secs: Seconds
    stats: dict[str, Any]


class Counts(FromNode, tag="counts"):
    published: dict[str, Count]
    received: dict[str, Count]
    held: dict[str, Count]
    pending: dict[str, Count] = msgspec.field(default_factory=dict)


class WaitIdle(FromNode, tag="wait_idle"):
    last: Flag = 0


class StopRequest(FromNode, tag="stop_request"):
    reason: str
    exit_code: ExitCode


class Final(FromNode, tag="final"):
    stats: dict[str, Any]


class Connect(Control, tag="connect"):
    endpoints: dict[str, str]


class Start(Control, tag="start"):
    pass


class Idle(Control, tag="idle"):
    pass


class Release(Control, tag="release"):
    pending: Flag = 0


class Busy(Control, tag="busy"):
    pass


class Stop(Control, tag="stop"):
    pass


class FromHost(Control):
    """A launcher's message to the launcher of another host of the graph."""

    host: str


class LinkHello(FromHost, tag="link_hello"):
    run_secret: str
    reply: Flag
    graph: str
    argv: str


class LinkBeat(FromHost, tag="link_beat"):
    ready: Flag


class LinkPing(FromHost, tag="link_ping"):
    t1: int


class LinkPong(FromHost, tag="link_pong"):
    t1: int
    t2: int
    t3: int


class LinkStop(FromHost, tag="link_stop"):
    reason: str
    exit_code: ExitCode


class LinkCounts(FromHost, tag="link_counts"):
    published: dict[str, Count]
    received: dict[str, Count]
    held: dict[str, Count]
    pending: dict[str, Count] = msgspec.field(default_factory=dict)
    last: Flag = 0


class LinkFinal(FromHost, tag="link_final"):
    published: dict[str, Count]


KINDS: dict[str, type[Control]] = {
    str(cls.__struct_config__.tag): cls
    for cls in (
        Hello,
        Ready,
        Heartbeat,
        Counts,
        WaitIdle,
        StopRequest,
        Final,
        Connect,
        Start,
        Idle,
        Release,
        Busy,
        Stop,
        LinkHello,
        LinkBeat,
        LinkPing,
        LinkPong,
        LinkStop,
        LinkCounts,
        LinkFinal,
    )
}
"""Every control message type by its ``kind``."""
