"""The launchers' link (``runtime.hostlink``): what the launcher does about each event,
and the link itself over CURVE in a namespace: joining, the clock, forged messages
refused, stops passed on, a silent host reported lost."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import msgpack
import pytest
import zmq

from messages.control import LinkCounts
from runtime import protocol
from runtime.hostlink import HostLink
from runtime.hostpolicy import Act, judge
from runtime.hosts import Hosts, check_hosts
from runtime.protocol import ControlError
from runtime.security import Guard
from tests.hosts.conftest import ROOT, free_port_range, host_table, write_graph

HOSTS = Hosts({}, on_host_lost="stop", host_timeout_secs=1.0, max_clock_offset_secs=0.005)


def test_judge_applies_the_policies() -> None:
    lost = judge(("lost", "robot", 1.2), HOSTS)
    assert lost.stop == "host 'robot' lost" and lost.exit_code == 1 and not lost.echo
    assert "no heartbeat for 1.2 s; on_host_lost: stop" in lost.lines[0]
    waiting = judge(("lost", "robot", 1.2), Hosts({}, on_host_lost="wait"))
    assert waiting.stop is None and "on_host_lost: wait" in waiting.lines[0]
    far = judge(("clock", "robot", 0.020, 0.002), HOSTS)  # 20 ms, measured within 1 ms
    assert far.stop == "clock offset to host 'robot'" and far.exit_code == 1
    assert "clock offset to host 'robot': +20.000 ms (round trip 2.000 ms" in far.lines[0]
    unsure = judge(("clock", "robot", 0.006, 0.004), HOSTS)  # above 5 ms, by less than 2
    assert unsure.stop is None and "warning" in unsure.lines[1]
    assert judge(("clock", "robot", -0.0001, 0.0005), HOSTS) == Act(
        ["clock offset to host 'robot': -0.100 ms (round trip 0.500 ms, limit 5 ms)"]
    )
    stop = judge(("stop", "robot", "supervisor: done", 3), HOSTS)
    assert stop.stop == "host 'robot' stops: supervisor: done"
    assert stop.verdict_code == 3 and not stop.echo
    assert judge(("back", "robot", True), HOSTS).lines == ["host 'robot' is back (a new launcher)"]
    theirs, ours = "python launch.py g.yaml --lockstep --record o.mcap", "python launch.py g.yaml"
    other = judge(("graph_differs", "robot", "ab" * 32, "cd" * 32, theirs, ours), HOSTS)
    assert other.stop == "host 'robot' runs another graph" and other.exit_code == 2
    assert "sha256 abababababab, here cdcdcdcdcdcd" in other.lines[0]
    assert other.lines[1] == (
        "host 'robot' was started with --lockstep --record o.mcap that this host was not, "
        "and this host with nothing that it was not"
    )
    same = judge(("graph_differs", "robot", "ab" * 32, "cd" * 32, ours, ours), HOSTS)
    assert len(same.lines) == 1  # the same options: another graph file


def test_a_closed_link_leaves_alone_the_descriptors_it_had() -> None:
    """Once closed, a link's pipes are closed and their numbers belong to whatever opens a
    file next (libzmq's mailboxes are eventfds): asking the closed link for events, or
    queueing a message on it, must neither read nor write them. Reading one stole a
    wake-up from libzmq, so that a connection made later never attached and a closed
    socket's port stayed bound."""
    errors: list[str] = []
    table = {h: {"address": "127.0.0.1", "ports": list(free_port_range(40))} for h in ("a", "b")}
    hosts = check_hosts({"hosts": table}, "g.yaml", errors)
    assert not errors
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    link = HostLink(ctx, hosts, "a", None, lambda _: None, {"g": 1})
    had = {link._wake_r, link._wake_w, link._note_r, link._note_w}
    link.start()
    link.close()
    # Socket pairs, whose ends both read and write, taking the lowest free numbers first:
    # every number the link had is one of their ends, whatever order they come in.
    pairs: list[tuple[socket.socket, socket.socket]] = []
    try:
        while not had <= {end.fileno() for pair in pairs for end in pair} and len(pairs) < 64:
            pairs.append(socket.socketpair())
        ends = [end for pair in pairs for end in pair]
        assert had <= {end.fileno() for end in ends}
        for end in ends:
            end.setblocking(False)
            end.send(b"x")  # for its peer to read
        assert link.events() == []
        link.send_stop("late", 0)
        link.set_ready()
        assert [end.recv(16) for end in ends] == [b"x"] * len(ends)  # none read, none written
    finally:
        for pair in pairs:
            for end in pair:
                end.close()
        ctx.term()


def test_the_guard_stops_answering_only_once_the_sockets_it_guards_are_closed() -> None:
    """A CURVE handshake that asks ZAP after the guard has stopped never ends, and libzmq
    then never finishes closing the socket: its port stays bound. A link closed while the
    other host's connection handshook left its host's port bound for good (1 in 30 to 200
    closes), so a launcher started again there could not bind it."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    guard = Guard(ctx, {}, lambda _: None)
    router = ctx.socket(zmq.ROUTER)
    guard.watch(router)
    guard.start()
    with pytest.raises(RuntimeError, match="close the sockets it guards first"):
        guard.close()
    router.close(linger=0)
    guard.close()
    ctx.term()


# Two links (hosts a and b on the namespace's own address), and a forger: a DEALER with
# a's key that claims to be b, then one with b's key whose tags are not b's secret; then b
# stops, and comes back with another graph.
LINKS = """
import json, sys, time, zmq
from pathlib import Path
from messages.control import LinkStop
from runtime import protocol
from runtime.graph import load_document
from runtime.hostlink import HostLink
from runtime.hosts import check_hosts
from runtime.security import connect_to, load_key

keys, graph = Path(sys.argv[1]), sys.argv[2]
hosts = check_hosts(load_document(graph), graph, [])
log = []
links = {
    h: HostLink(zmq.Context(), hosts, h, load_key(keys / f"{h}.key"), lambda t, h=h: log.append([h, t]), {"g": 1})
    for h in ("a", "b")
}
events = []

def has(*event):
    return any(tuple(e[: len(event)]) == event for e in events)

def refused(host):
    return sum("link: refused message #" in t for h, t in log if h == host)

# Gather the links' events until done(): each comes on its own, however loaded the
# machine; the bound only ends a run where one never does, saying what came.
def collect(done, what):
    end = time.monotonic() + 60
    while not done():
        if time.monotonic() > end:
            sys.exit(f"no {what} in 60 s: {json.dumps({'events': events, 'log': log})}")
        for h, link in links.items():
            events.extend([h, *e] for e in link.events())
        time.sleep(0.02)

def joined():
    return all(has(h, "joined", p) and has(h, "clock", p) for h, p in (("a", "b"), ("b", "a")))

for link in links.values():
    link.start()
collect(joined, "join and clock of both")
ctx = zmq.Context()
for n, (key, secret) in enumerate((("a", b"x" * 32), ("b", b"y" * 32)), 1):
    forger = ctx.socket(zmq.DEALER)
    connect_to(forger, load_key(keys / f"{key}.key"), hosts.table["a"].public_key)
    forger.connect(hosts.table["a"].link)
    forger.send_multipart(
        protocol.pack(secret, LinkStop(host="b", reason="forged", exit_code=9))
    )
    collect(lambda n=n: refused("a") >= n, f"refusal #{n}")
    forger.close(linger=0)
links["b"].send_stop("supervisor: done", 0)
collect(lambda: has("a", "stop", "b"), "stop")
links["b"].close()
collect(lambda: has("a", "lost", "b"), "loss")
# b again (the same graph), stopping in order this time: its final counts, then its exit.
# a, still stopping, must not call it lost however long it stays silent after that.
again = HostLink(zmq.Context(), hosts, "b", load_key(keys / "b.key"), print, {"g": 1})
again.start()
collect(lambda: has("a", "back", "b"), "back")
again.send_final({"n/tick": 3})
collect(lambda: links["a"].finals() is not None, "final")
again.close()
end = time.monotonic() + 3 * hosts.host_timeout_secs
while time.monotonic() < end:
    events.extend(["a", *e] for e in links["a"].events())
    time.sleep(0.05)
# b's launcher again, with another graph: a does not let it in.
other = HostLink(zmq.Context(), hosts, "b", load_key(keys / "b.key"), print, {"g": 2})
other.start()
collect(lambda: has("a", "graph_differs", "b"), "graph_differs")
other.close()
links["a"].close()
print(json.dumps({"events": events, "log": log}))
"""


def test_the_link_joins_measures_refuses_forgeries_passes_stops_and_sees_a_loss(
    netns, tmp_path: Path
) -> None:
    table = host_table(tmp_path, ["a", "b"])
    table["b"]["address"] = table["a"]["address"]  # both in the first namespace
    table["b"]["ports"] = [24100, 24140]
    graph = write_graph(
        {"hosts": table, "host_timeout_secs": 1.0, "nodes": {"n": {"impl": "synthetic.source"}}},
        tmp_path / "g.yaml",
    )
    done = subprocess.run(
        netns[0].command([sys.executable, "-c", LINKS, str(tmp_path), str(graph)]),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout)
    events = [tuple(e[:3]) for e in out["events"]]
    assert ("a", "joined", "b") in events and ("b", "joined", "a") in events
    clocks = [e for e in out["events"] if e[1] == "clock"]
    assert {e[0] for e in clocks} == {"a", "b"}
    # One machine's clock: the offset measured is within half the round trip, however
    # slow the round trip (t1 <= t2 <= t3 <= t4 on one clock).
    assert all(e[4] > 0 and abs(e[3]) <= e[4] / 2 + 1e-9 for e in clocks), clocks
    log = "\n".join(text for _, text in out["log"])
    assert "link: refused message #1: claims to be host 'b', but its key is 'a''s" in log
    assert "link: refused message #2: from host 'b': tag does not match" in log
    stops = [e for e in out["events"] if e[1] == "stop"]
    assert stops == [["a", "stop", "b", "supervisor: done", 0]]  # only b's own, not forged
    assert events.count(("a", "lost", "b")) == 1  # not again after b's final counts
    assert ("a", "graph_differs", "b") in events
    assert events.count(("a", "back", "b")) == 1  # b again; not the other graph


def test_link_counts_are_checked_field_by_field() -> None:
    secret = protocol.new_secret()
    good = protocol.pack(
        secret, LinkCounts(host="b", published={"a/t": 3}, received={"n/p": 3}, held={})
    )
    msg = protocol.unpack(secret, good, from_node=False)
    assert isinstance(msg, LinkCounts) and msg.received == {"n/p": 3}
    for bad, why in (
        (
            {"published": {"a/t": -1}, "received": {}, "held": {}},
            r">= 0 - at `\$\.published\[\.\.\.\]`",
        ),
        (
            {"published": {}, "received": {"n/p": "3"}, "held": {}},
            r"`int`, got `str` - at `\$\.received",
        ),
        (
            {"published": {}, "received": {}, "held": {"n/p": -1}},
            r">= 0 - at `\$\.held\[\.\.\.\]`",
        ),
        ({"published": {}}, "link_counts: Object missing required field `received`"),
    ):
        payload = msgpack.packb({"kind": "link_counts", "host": "b", **bad})
        frames = [payload, protocol._tag(secret, payload)]
        with pytest.raises(ControlError, match=why):
            protocol.unpack(secret, frames, from_node=False)
