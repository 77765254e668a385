"""Record a synthetic graph with real processes, replay it in lockstep, swap a node.

Each run starts a handful of node processes (a few seconds in all on a loaded machine).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

import nodes.recorder  # noqa: F401  (registers the implementations the graphs name)
import nodes.replay  # noqa: F401
import tests.synthetic_nodes  # noqa: F401  (registers the synthetic nodes)
from cli.run import launch
from messages import Header, Tick
from runtime.bag import BagReader
from runtime.bag.diff import diff_bags
from runtime.graph import check
from runtime.node import Node
from runtime.replaygraph import ReplayOptions, build_replay_graph

GRAPH = yaml.safe_load(
    """
nodes:
  source_a: {impl: synthetic.source, params: {rate_hz: 200, count: 40}}
  source_b: {impl: synthetic.source, params: {rate_hz: 80, count: 16, stop_when_done: false}}
  relay: {impl: synthetic.relay, params: {add: 1000}, inputs: {tick: source_a/tick}}
  merge: {impl: synthetic.merge, inputs: {a: relay/tick, b: source_b/tick}}
  sink: {impl: synthetic.sink, inputs: {tick: merge/tick}}
"""
)


class ScaledRelay(Node):
    """A different implementation of the relay: doubles the value (used through module:Class)."""

    inputs = {"tick": Tick}
    outputs = {"tick": Tick}

    def on_tick(self, msg: Tick) -> None:
        out = Tick(header=Header(stamp_nanos=msg.header.stamp_nanos), value=2.0 * msg.value)
        self.io.publish("tick", out)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "live.mcap"
    code = launch(GRAPH, source="test graph", record=path, log_level="WARNING", command_line="test")
    assert code == 0
    return path


def replay(bag: Path, out: Path, replace: dict[str, str]) -> None:
    graph = build_replay_graph(GRAPH, bag, replace, ReplayOptions(lockstep=True))
    code = launch(graph, source="replay", record=out, lockstep=True, log_level="WARNING")
    assert code == 0


def values(path: Path, topic: str) -> list[float]:
    with BagReader(path) as r:
        return [m.decode_plain()["value"] for m in r.messages([topic])]


def test_recording_holds_every_topic_and_the_graph(recorded: Path) -> None:
    with BagReader(recorded) as r:
        assert r.has_summary and not r.problems
        stats = r.stats()
        assert {t: s.messages for t, s in stats.items()} == {
            "source_a/tick": 40,
            "source_b/tick": 16,
            "relay/tick": 40,
            "merge/tick": 56,
        }
        assert all(d["runtime"] == 0 and d["seq_gaps"] == 0 for d in r.drops().values())
        stored = yaml.safe_load(r.run_info()["graph_yaml"])
        assert set(stored["nodes"]) == set(GRAPH["nodes"])
    assert values(recorded, "relay/tick") == [1000.0 + i for i in range(40)]


def test_lockstep_replay_is_deterministic_and_a_swap_changes_it(
    recorded: Path, tmp_path: Path
) -> None:
    first, second, swapped = tmp_path / "r1.mcap", tmp_path / "r2.mcap", tmp_path / "r3.mcap"
    replay(recorded, first, {"relay": ""})
    replay(recorded, second, {"relay": ""})
    assert diff_bags(first, second) == []
    merged = values(first, "merge/tick")
    # In lockstep the merge sees its inputs in exactly the bag's order of the sources.
    with BagReader(recorded) as r:
        order = [
            (1000.0 if m.topic == "source_a/tick" else 0.0) + m.decode_plain()["value"]
            for m in r.messages(["source_a/tick", "source_b/tick"])
        ]
    assert merged == order and len(merged) == 56
    # The replayed sources are exactly the recorded ones.
    assert diff_bags(recorded, first, ["source_a/tick", "source_b/tick"]) == []

    replay(recorded, swapped, {"relay": f"{__name__}:ScaledRelay"})
    assert values(swapped, "relay/tick") == [2.0 * i for i in range(40)]
    diffs = diff_bags(first, swapped, ["relay/tick"])
    assert len(diffs) == 40 and all(d.field == "value" for d in diffs)


def test_lockstep_pipelines_what_no_fan_in_can_reorder(recorded: Path, tmp_path: Path) -> None:
    # Rerun only the merge: both its inputs now come from the replay, one publisher,
    # so no message needs an idle wait and the merge still sees the bag's order.
    graph = build_replay_graph(GRAPH, recorded, {"merge": ""}, ReplayOptions(lockstep=True))
    assert check(graph).barrier_topics() == set()
    out = tmp_path / "pipelined.mcap"
    assert launch(graph, source="replay", record=out, lockstep=True, log_level="WARNING") == 0
    with BagReader(recorded) as r:
        order = [m.decode_plain()["value"] for m in r.messages(["relay/tick", "source_b/tick"])]
    assert values(out, "merge/tick") == order and len(order) == 56


# Two ordered fan-ins, one upstream of the other, both reached by one replayed message:
# ``merge2`` reads ``source_b`` from the replay and, through ``merge`` and a slow relay,
# again. Released together, ``merge2`` would handle the direct copy before the slow one
# arrived; released upstream first, it holds both and handles them by stamp, then port.
CHAIN = yaml.safe_load(
    """
nodes:
  source_a: {impl: synthetic.source, params: {rate_hz: 200, count: 12}}
  source_b: {impl: synthetic.source, params: {rate_hz: 80, count: 6, stop_when_done: false}}
  relay: {impl: synthetic.relay, params: {add: 1000}, inputs: {tick: source_a/tick}}
  merge: {impl: synthetic.merge, inputs: {a: relay/tick, b: source_b/tick}}
  slow: {impl: synthetic.relay, params: {add: 100000, work_secs: 0.05}, inputs: {tick: merge/tick}}
  merge2: {impl: synthetic.merge, inputs: {a: slow/tick, b: source_b/tick}}
"""
)


def test_lockstep_releases_an_upstream_fan_in_before_a_downstream_one(tmp_path: Path) -> None:
    live = tmp_path / "live.mcap"
    assert launch(CHAIN, source="chain", record=live, log_level="WARNING", command_line="t") == 0
    rerun = dict.fromkeys(("relay", "merge", "slow", "merge2"), "")
    graph = build_replay_graph(CHAIN, live, rerun, ReplayOptions(lockstep=True))
    assert check(graph).fan_ins() == {"merge", "merge2"}
    out = tmp_path / "replayed.mcap"
    assert launch(graph, source="replay", record=out, lockstep=True, log_level="WARNING") == 0
    expected: list[float] = []
    with BagReader(live) as r:
        for m in r.messages(["source_a/tick", "source_b/tick"]):
            value = m.decode_plain()["value"]
            if m.topic == "source_a/tick":
                expected.append(value + 1000 + 100000)
            else:  # the copy through merge and slow (port a), then the direct one (port b)
                expected += [value + 100000, value]
    assert values(out, "merge2/tick") == expected and len(expected) == 12 + 2 * 6


def _pid_holding(path: Path, parent: int) -> int | None:
    """The child of ``parent`` that has ``path`` open (Linux /proc), if any."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid != parent:
                continue
            for fd in (entry / "fd").iterdir():
                if Path(os.readlink(fd)) == path:
                    return int(entry.name)
        except (OSError, ValueError, IndexError):
            continue
    return None


@pytest.mark.skipif(not Path("/proc/self/fd").exists(), reason="needs Linux /proc")
def test_sigkilled_recorder_leaves_a_readable_bag(tmp_path: Path) -> None:
    bag = (tmp_path / "killed.mcap").resolve()
    root = Path(__file__).resolve().parents[2]
    # launch() in a child of its own (it is the one killed node's parent), importing only
    # the node modules it needs.
    script = (
        "import sys, tests.synthetic_nodes, nodes.recorder\n"
        "from cli.run import launch\n"
        "graph = {'nodes': {'src': {'impl': 'synthetic.source',"
        " 'params': {'rate_hz': 100, 'count': 100000}}}}\n"
        "sys.exit(launch(graph, source='g', record=sys.argv[1], log_level='WARNING'))\n"
    )
    launcher = subprocess.Popen(
        [sys.executable, "-c", script, str(bag)],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        pid = None
        while pid is None and time.monotonic() < deadline and launcher.poll() is None:
            time.sleep(0.1)
            pid = _pid_holding(bag, launcher.pid)
        assert pid is not None, "the recorder never opened the bag"
        with BagReader(bag, warn=lambda _: None) as r:
            start = len(list(r.messages()))
        while time.monotonic() < deadline:  # let it record past a few flushes
            time.sleep(0.3)
            with BagReader(bag, warn=lambda _: None) as r:
                if len(list(r.messages())) >= start + 50:
                    break
        os.kill(pid, signal.SIGKILL)
        launcher.wait(timeout=60)
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    with BagReader(bag, warn=lambda _: None) as r:
        assert not r.has_summary
        seqs = [m.sequence for m in r.messages(["src/tick"])]
        assert len(seqs) >= 50
        assert seqs == list(range(len(seqs))), "everything up to the last flush, in order"
        assert "synthetic.source" in r.run_info()["graph_yaml"]
