"""One graph on two or three hosts made as network namespaces (10.77.0.1, .2, .3), each
with its own launcher (``ip netns exec NS python launch.py GRAPH --host NAME``); CURVE
on every tcp endpoint. Skipped with the reason where namespaces cannot be made."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

from runtime.bag import BagReader
from runtime.bag.diff import diff_bags
from runtime.graph import load_document
from runtime.hosts import check_hosts
from tests.hosts.conftest import ROOT, Launched, host_table, two_host_graph, write_graph
from tests.runtime.conftest import topic_messages

ROBOT = ["world", "left_camera", "right_camera", "left_pressure", "right_pressure", "gripper"]
# Subscribers on the third host: a plain SUB, then a CURVE SUB with a key of its own,
# each given 1.5 s; prints how many messages each got.
INTRUDER = """
import sys, time, zmq
endpoint, server_key = sys.argv[1], sys.argv[2].encode()
ctx = zmq.Context()
for curve in (False, True):
    sock = ctx.socket(zmq.SUB)
    if curve:
        sock.curve_serverkey = server_key
        sock.curve_publickey, sock.curve_secretkey = zmq.curve_keypair()
    sock.subscribe(b"")
    sock.connect(endpoint)
    got, end = 0, time.monotonic() + 1.5
    while time.monotonic() < end:
        while sock.poll(10):
            sock.recv()
            got += 1
    print(got)
"""


def tcp_sockets(ns_command: list[str]) -> list[tuple[str, str, str]]:
    """``(state, local, peer)`` of every tcp socket in a namespace (``ss``)."""
    out = subprocess.run(
        [*ns_command, "ss", "-Htan"], capture_output=True, text=True, check=True
    ).stdout
    return [(f[0], f[3], f[4]) for f in (line.split() for line in out.splitlines()) if len(f) >= 5]


def split_handover(keys: Path) -> dict:
    """The handover graph (graph.yaml) on hosts robot (10.77.0.1) and workstation (.2)."""
    doc = load_document(ROOT / "graph.yaml")
    doc["hosts"] = host_table(keys, ["robot", "workstation"])
    for name, node in doc["nodes"].items():
        node["host"] = "robot" if name in ROBOT else "workstation"
    # Half real time: the task must end before the scene does, and the scene runs on the
    # clock whether or not a loaded machine's perception kept up.
    doc["nodes"]["world"]["params"]["rate_scale"] = 0.5
    return doc


def test_the_handover_split_across_hosts_runs_end_to_end_records_and_refuses_intruders(
    netns, launched, tmp_path: Path
) -> None:
    doc = split_handover(tmp_path)
    # Recording across hosts: a recorder node in the graph, on the workstation.
    bag = tmp_path / "run.mcap"
    doc["nodes"]["recorder"] = {
        "impl": "recorder",
        "host": "workstation",
        "params": {"path": str(bag)},
        "inputs": {"t0": {"from": "world/state", "queue_size": 10000}},
    }
    graph = write_graph(doc, tmp_path / "handover.yaml")
    robot_ns, ws_ns, outside = netns
    robot = Launched.host(robot_ns, graph, "robot", tmp_path, tmp_path / "robot.log")
    workstation = Launched.host(ws_ns, graph, "workstation", tmp_path, tmp_path / "ws.log")
    launched += [robot, workstation]
    robot.wait_for("all nodes ready; running")
    # Checked at once, while the graph surely runs (it ends by itself within seconds).
    # Traffic only on the namespaces' own addresses: every tcp socket there is 10.77.0.x.
    for ns in (robot_ns, ws_ns):
        sockets = tcp_sockets(ns.command([]))
        assert sockets, "no tcp socket in the namespace"
        assert any(state == "ESTAB" for state, _, _ in sockets)
        for state, local, peer in sockets:
            assert local.startswith("10.77.0."), (state, local, peer)
            assert state == "LISTEN" or peer.startswith("10.77.0."), (state, local, peer)

    hosts = check_hosts(doc, "handover.yaml", [])
    world = hosts.endpoints({n: body["host"] for n, body in doc["nodes"].items()})["world"]
    assert world.startswith("tcp://10.77.0.1:")
    intruder = subprocess.run(
        outside.command(
            [sys.executable, "-c", INTRUDER, world, doc["hosts"]["robot"]["public_key"]]
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert intruder.stdout.split() == ["0", "0"], intruder.stderr  # nothing, encrypted or not

    assert workstation.finish() == 0, workstation.text[-3000:]
    assert robot.finish() == 0, robot.text[-3000:]
    ws_out, robot_out = workstation.text, robot.text
    assert "handover: stable" in ws_out  # robot's sensors -> workstation's monitor
    assert "stopping: host 'workstation' stops" in robot_out
    for topic in ("left_camera/image", "contact_patch/patch", "pose/pose", "shear/shear"):
        assert topic_messages(ws_out, topic) > 0, topic
    assert topic_messages(robot_out, "supervisor/command") > 0  # and back, to the gripper
    assert re.search(r"clock offset to host 'workstation': [+-]\d+\.\d+ ms", robot_out)
    info = subprocess.run(
        [sys.executable, "launch.py", "bag", "info", str(bag)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    recorded = next(line for line in info.stdout.splitlines() if line.startswith("world/state "))
    assert int(recorded.split()[2]) == topic_messages(robot_out, "world/state")  # every one
    # Both intruders are refused and logged: first the plain one (its handshake fails;
    # its address is unknown when it was gone before the monitor read it), then the CURVE
    # one, with its address and key.
    where = r"refused a peer at (10\.77\.0\.3|an unknown address) \(1 time\(s\)\): (.*)"
    refusals = re.findall(where, robot_out)
    assert len(refusals) >= 2, robot_out
    assert "plain ZeroMQ" in refusals[0][1] or "the handshake failed" in refusals[0][1]
    assert any(
        peer == "10.77.0.3"
        and re.fullmatch(r"CURVE key \S{40} is not one of the graph's hosts", why)
        for peer, why in refusals
    )


def test_a_killed_host_is_reported_within_the_timeout_and_stops_the_graph(
    netns, launched, tmp_path: Path
) -> None:
    graph = write_graph(two_host_graph(tmp_path, count=100000), tmp_path / "g.yaml")
    argv = [
        sys.executable,
        "launch.py",
        str(graph),
        "--check",
        "--host",
        "a",
        "--keys",
        str(tmp_path),
    ]
    checked = subprocess.run(netns[0].command(argv), cwd=ROOT, capture_output=True, text=True)
    assert "OK, 2 nodes, 1 edges; host a, its key matches" in checked.stdout, checked.stderr
    a = Launched.host(netns[0], graph, "a", tmp_path, tmp_path / "a.log")
    b = Launched.host(netns[1], graph, "b", tmp_path, tmp_path / "b.log")
    launched += [a, b]
    b.wait_for("all nodes ready; running")
    b.wait_for("clock offset to host 'a'")
    a.kill()
    b.wait_for("host 'a' lost", timeout=30)
    # Lost once host_timeout_secs (1.5 s) passed without a heartbeat, not sooner (how
    # much later a loaded machine notices is bench.hosts' to measure, not a test's).
    silent = re.search(r"no heartbeat for ([\d.]+) s", b.text)
    assert silent is not None and float(silent.group(1)) >= 1.5, b.text
    assert "on_host_lost: stop" in b.text
    assert b.finish() == 1
    assert "stopping: host 'a' lost" in b.text


def test_with_on_host_lost_wait_a_host_that_comes_back_is_resubscribed(
    netns, launched, tmp_path: Path
) -> None:
    graph = write_graph(two_host_graph(tmp_path, policy="wait", count=40), tmp_path / "g.yaml")
    a = Launched.host(netns[0], graph, "a", tmp_path, tmp_path / "a.log")
    b = Launched.host(netns[1], graph, "b", tmp_path, tmp_path / "b.log")
    launched += [a, b]
    a.wait_for("all nodes ready; running")
    time.sleep(0.5)
    a.kill()
    b.wait_for("host 'a' lost", timeout=30)
    assert b.proc.poll() is None  # the sink's host goes on
    again = Launched.host(netns[0], graph, "a", tmp_path, tmp_path / "a2.log")
    launched.append(again)
    b.wait_for("host 'a' is back (a new launcher)")
    # The new source waits for the sink, whose socket reconnects and subscribes again,
    # sends all its ticks and ends the graph on both hosts.
    assert again.finish() == 0, again.text[-3000:]
    assert b.finish() == 0, b.text[-3000:]
    received = int(re.search(r"received (\d+) ticks", b.text).group(1))
    assert received > 40, b.text[-2000:]  # before the kill, and all 40 of the new source
    assert b.text.count("[launch] starting 1 node(s)") == 1  # the sink was not restarted


def test_the_handover_recorded_across_hosts_replays_in_lockstep_across_them_as_on_one(
    netns, launched, tmp_path: Path
) -> None:
    doc = split_handover(tmp_path)
    graph = write_graph(doc, tmp_path / "handover.yaml")
    bag, keys = tmp_path / "run.mcap", ["--keys", tmp_path]
    # --record on both hosts: the recorder runs on the first (robot), over CURVE from the other.
    on = [(netns[0], "robot"), (netns[1], "workstation")]
    record = [graph, "--record", bag, "--log-level", "WARNING", *keys]
    launched += [Launched([*record, "--host", h], tmp_path / f"rec-{h}.log", ns) for ns, h in on]
    assert [item.finish() for item in launched] == [0, 0], launched[1].text[-3000:]
    with BagReader(bag) as reader:
        counts = {t: s.messages for t, s in reader.stats().items()}
    assert counts["world/state"] == topic_messages(launched[0].text, "world/state")
    assert counts["shear/shear"] > 0 and counts["pose/pose"] > 0  # from the workstation

    # The shear tracker rerun in lockstep: the replay (robot) feeds it on the workstation,
    # whose counts come back over the link before every barrier; then on one host.
    replay = ["replay", bag, "--swap", "shear", "--lockstep", "--log-level", "WARNING"]
    split, alone = tmp_path / "split.mcap", tmp_path / "alone.mcap"
    runs = [
        Launched([*replay, "--record", split, *keys, "--host", h], tmp_path / f"{h}.log", ns)
        for ns, h in on
    ]
    launched += runs
    assert [item.finish() for item in runs] == [0, 0], runs[1].text[-3000:]
    one = Launched([*replay, "--record", alone, "--no-hosts"], tmp_path / "alone.log")
    launched.append(one)
    assert one.finish() == 0, one.text[-3000:]
    assert diff_bags(alone, split, ["shear/shear"]) == []
    shear = []
    for path in (alone, split):
        with BagReader(path) as reader:
            shear.append(reader.stats()["shear/shear"].messages)
    assert shear[0] == shear[1] > 0
