"""``bag info|echo|diff`` and the replay graph builder (no processes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import nodes.recorder  # noqa: F401  (registers the implementations the graphs name)
import nodes.replay  # noqa: F401
import tests.synthetic_nodes  # noqa: F401  (registers the synthetic nodes)
from cli.main import main as cli_main
from messages.base import Header
from messages.errors import GraphError
from messages.types import PoseEstimate, Tick, ToFImage
from runtime.bag import BagWriter
from runtime.bag.diff import compare_values, diff_bags
from runtime.node import Node
from runtime.replaygraph import ReplayOptions, build_replay_graph, exact_topics
from tests.runtime.bad_bags import bag_with_undecodable

GRAPH = yaml.safe_load(
    """
nodes:
  source_a: {impl: synthetic.source, params: {rate_hz: 100, count: 10}}
  source_b: {impl: synthetic.source, params: {rate_hz: 50, count: 5, stop_when_done: false}}
  relay: {impl: synthetic.relay, params: {add: 1000}, inputs: {tick: source_a/tick}}
  merge: {impl: synthetic.merge, inputs: {a: relay/tick, b: source_b/tick}}
  sink: {impl: synthetic.sink, inputs: {tick: merge/tick, other: {from: source_b/tick, policy: latest}}}
  rec: {impl: recorder, params: {path: old.mcap}, inputs: {t0: merge/tick}}
"""
)
ALL = ("source_a/tick", "source_b/tick", "relay/tick", "merge/tick")


def make_bag(
    path: Path, topics: tuple[str, ...] = ALL, values: dict[str, float] | None = None
) -> Path:
    with BagWriter(path) as w:
        w.add_run_info(graph_text=yaml.safe_dump(GRAPH), command_line="launch.py g.yaml")
        for i in range(3):
            for topic in topics:
                value = (values or {}).get(topic, 0.0) + i
                msg = Tick(header=Header(stamp_nanos=i, seq=i), value=value)
                w.write_message(topic, msg, log_time_nanos=i * 1_000_000)
    return path


def replay_params(graph: dict) -> dict:
    (replay,) = [n for n in graph["nodes"].values() if n["impl"] == "replay"]
    return replay["params"]


# -- build_replay_graph --------------------------------------------------------------------------


def test_replacing_a_node_runs_it_and_its_downstream_live(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    graph = build_replay_graph(
        GRAPH, bag, {"relay": "synthetic.relay"}, ReplayOptions(lockstep=True)
    )
    assert set(graph["nodes"]) == {"relay", "merge", "sink", "replay"}
    params = replay_params(graph)
    assert params["topics"] == exact_topics(["source_a/tick", "source_b/tick"])
    assert params["lockstep"] is True and params["path"] == str(bag)
    assert GRAPH["nodes"]["relay"]["impl"] == "synthetic.relay"  # the input is not modified


def test_replacing_a_sink_replays_its_inputs(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    graph = build_replay_graph(GRAPH, bag, {"sink": ""})
    assert set(graph["nodes"]) == {"sink", "replay"}
    assert replay_params(graph)["topics"] == exact_topics(["merge/tick", "source_b/tick"])


def test_new_impl_is_applied(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    graph = build_replay_graph(GRAPH, bag, {"merge": "synthetic.merge", "sink": "synthetic.sink"})
    assert graph["nodes"]["merge"]["impl"] == "synthetic.merge"
    assert replay_params(graph)["topics"] == exact_topics(["relay/tick", "source_b/tick"])


def test_topics_missing_from_the_bag_pull_their_producers_in(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap", topics=("source_b/tick", "merge/tick"))
    graph = build_replay_graph(GRAPH, bag, {"merge": ""})
    # merge needs relay/tick (not recorded), relay needs source_a/tick (not recorded either).
    assert set(graph["nodes"]) == {"source_a", "relay", "merge", "sink", "replay"}
    assert replay_params(graph)["topics"] == exact_topics(["source_b/tick"])


def test_topic_selection_and_remap(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap", topics=("cam/a", "source_b/tick"))
    options = ReplayOptions(remap={"cam/a": "source_a/tick"}, fast=True)
    graph = build_replay_graph(GRAPH, bag, {"relay": ""}, options)
    params = replay_params(graph)
    assert params["topics"] == exact_topics(["cam/a", "source_b/tick"])
    assert params["remap"] == {"cam/a": "source_a/tick"}
    assert "source_a" not in graph["nodes"]
    graph = build_replay_graph(
        GRAPH, make_bag(tmp_path / "b.mcap"), {"relay": ""}, ReplayOptions(topics="source_b/.*")
    )
    assert "source_a" in graph["nodes"]  # not selected from the bag: runs live


def test_nothing_replaced_replays_everything(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    graph = build_replay_graph(GRAPH, bag, {})
    assert set(graph["nodes"]) == {"replay"}
    assert replay_params(graph)["topics"] == exact_topics(
        ["merge/tick", "relay/tick", "source_a/tick", "source_b/tick"]
    )


def test_replay_graph_errors(tmp_path: Path) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    with pytest.raises(GraphError, match="no node 'pose'"):
        build_replay_graph(GRAPH, bag, {"pose": "x"})
    with pytest.raises(GraphError, match="unknown implementation"):
        build_replay_graph(GRAPH, bag, {"relay": "no.such.impl"})


def test_replay_main_prints_the_graph_from_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    code = cli_main(
        [
            "replay",
            str(bag),
            "--swap",
            "relay=synthetic.relay",
            "--fast",
            "--start",
            "0.5",
            "--print-graph",
        ]
    )
    assert code == 0
    graph = yaml.safe_load(capsys.readouterr().out)
    assert set(graph["nodes"]) == {"relay", "merge", "sink", "replay"}
    assert graph["nodes"]["replay"]["params"]["fast"] is True
    assert graph["nodes"]["replay"]["params"]["start_secs"] == 0.5
    assert cli_main(["replay", str(bag), "--swap", "ghost", "--print-graph"]) == 2
    assert "no node 'ghost'" in capsys.readouterr().err


# -- info and echo -------------------------------------------------------------------------------


def test_info_lists_topics_counts_drops_and_graph(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        w.add_run_info(
            graph_text=yaml.safe_dump(GRAPH), graph_source="g.yaml", command_line="run it"
        )
        for seq in (0, 1, 3):
            w.write_message(
                "a/tick", Tick(header=Header(seq=seq)), log_time_nanos=seq * 100_000_000
            )
        w.set_runtime_drops({"a/tick": 1})
    assert cli_main(["bag", "info", str(path), "--graph"]) == 0
    out = capsys.readouterr().out
    assert "summary:   yes" in out and "duration:  0.300 s" in out
    assert "recorded:  run it" in out and "graph:     g.yaml" in out
    row = next(line for line in out.splitlines() if line.startswith("a/tick"))
    assert row.split() == ["a/tick", "Tick", "3", "6.67", "0.00", "1", "1"]
    assert "DROPPED" in out
    assert "synthetic.relay" in out  # --graph prints the stored graph


def test_echo_decodes_and_summarizes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "a.mcap"
    depth = np.full((4, 5), 0.1, np.float32)
    depth[0, 0] = np.nan
    msg = ToFImage(
        header=Header(seq=2),
        sensor="left",
        depth_m=depth,
        ir=np.arange(20, dtype=np.uint16).reshape(4, 5),
        fx_px=1.0,
        fy_px=1.0,
        cx_px=2.0,
        cy_px=1.5,
    )
    with BagWriter(path) as w:
        w.write_message("cam/image", msg, log_time_nanos=5)
    assert cli_main(["bag", "echo", str(path), "--topic", "cam/image"]) == 0
    out = capsys.readouterr().out
    assert "--- cam/image #0 ToFImage seq 2" in out
    assert "sensor: left" in out
    assert "depth_m: float32[4x5] min 0.1 max 0.1 mean 0.1 non-finite 1" in out
    assert "ir: uint16[4x5] min 0 max 19 mean 9.5" in out
    assert cli_main(["bag", "echo", str(path), "--topic", "nope/x"]) == 2
    err = capsys.readouterr().err
    assert "a.mcap: topic 'nope/x' is not in the bag" in err


def test_info_of_a_file_that_is_not_a_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "x.mcap"
    path.write_text("hello")
    assert cli_main(["bag", "info", str(path)]) == 2
    assert "x.mcap: not an MCAP file" in capsys.readouterr().err


# -- diff ----------------------------------------------------------------------------------------


def test_diff_identical_and_different(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = make_bag(tmp_path / "a.mcap")
    b = make_bag(tmp_path / "b.mcap")
    c = make_bag(tmp_path / "c.mcap", values={"merge/tick": 1e-6})
    assert cli_main(["bag", "diff", str(a), str(b), "--topic", "merge/tick"]) == 0
    assert "no differences" in capsys.readouterr().out
    assert cli_main(["bag", "diff", str(a), str(c), "--topic", "merge/tick"]) == 1
    out = capsys.readouterr().out
    assert "merge/tick #0 value: 0.0 vs 1e-06" in out and "3 difference(s) in 3 message(s)" in out
    assert cli_main(["bag", "diff", str(a), str(c), "--topic", "merge/tick", "--atol", "1e-5"]) == 0
    assert cli_main(["bag", "diff", str(a), str(c), "--topic", "relay/tick"]) == 0
    assert cli_main(["bag", "diff", str(a), str(c)]) == 1  # every topic
    assert (
        cli_main(["bag", "diff", str(a), str(c), "--topic", "merge/tick", "--ignore", "value"]) == 0
    )
    assert cli_main(["bag", "diff", str(a), str(c), "--topic", "x/y"]) == 2


def test_diff_counts_and_arrays(tmp_path: Path) -> None:
    a = make_bag(tmp_path / "a.mcap", topics=("t/x",))
    short = tmp_path / "s.mcap"
    with BagWriter(short) as w:
        w.write_message("t/x", Tick(header=Header(), value=0.0), log_time_nanos=0)
    diffs = diff_bags(a, short, ["t/x"])
    assert any(d.field == "(count)" and "3 vs 1" in d.detail for d in diffs)
    x = np.array([1.0, np.nan, 3.0])
    assert compare_values({"v": x}, {"v": x.copy()}, rtol=0, atol=0) == []
    (found,) = compare_values({"v": x}, {"v": x + [0, 0, 1]}, rtol=0, atol=0)
    assert found[0] == "v" and "1 of 3 elements differ, max |a-b| 1" in found[1]
    (found,) = compare_values({"v": x}, {"v": x[:2]}, rtol=0, atol=0)
    assert "float64[3] vs float64[2]" in found[1]
    assert compare_values({"h": {"s": 1}}, {"h": {"s": 2}}, rtol=0, atol=0) == [("h.s", "1 vs 2")]
    assert (
        compare_values({"h": {"s": 1}}, {"h": {"s": 2}}, rtol=0, atol=0, ignore=frozenset({"h.s"}))
        == []
    )
    assert compare_values([True], [False], rtol=1, atol=1) == [("[0]", "True vs False")]


def pose_bag(path: Path, stamps: list[int], *, solve_secs: float = 0.01, x_m: float = 0.0) -> Path:
    """Poses answering patches of these stamps (a pose carries its patch's stamp)."""
    with BagWriter(path) as w:
        for seq, stamp in enumerate(stamps):
            pose = np.eye(4)
            pose[0, 3] = x_m if stamp == 3_000 else 0.0
            msg = PoseEstimate(
                header=Header(stamp_nanos=stamp, seq=seq),
                tool_from_object=pose,
                residual_rms_m=0.001,
                cost=0.0,
                iterations=3,
                status="ok",
                solve_secs=solve_secs,
                points_used=100,
            )
            w.write_message("pose/pose", msg, log_time_nanos=stamp)
    return path


def test_diff_pairs_by_stamp_and_reports_one_dropped_message_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stamps = [1_000 * k for k in range(1, 11)]
    full = pose_bag(tmp_path / "full.mcap", stamps)
    # Another replay that dropped the 5th pose, one that solved slower (a wall-clock
    # field) and one whose pose for the 3rd patch moved.
    dropped = pose_bag(tmp_path / "dropped.mcap", stamps[:4] + stamps[5:])
    slower = pose_bag(tmp_path / "slower.mcap", stamps, solve_secs=0.5)
    moved = pose_bag(tmp_path / "moved.mcap", stamps, x_m=0.01)
    diffs = diff_bags(full, dropped)
    assert [(d.field, d.index, d.stamp) for d in diffs] == [
        ("(count)", -1, None),
        ("(only in A)", 4, 5_000),
    ]
    assert cli_main(["bag", "diff", str(full), str(dropped)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out == [
        "pose/pose (count): 10 vs 9 messages",
        "pose/pose #4 stamp 5000 (only in A): PoseEstimate seq 4",
        "1 message(s) only in A",
    ]
    assert cli_main(["bag", "diff", str(dropped), str(full)]) == 1
    assert "1 message(s) only in B" in capsys.readouterr().out
    assert diff_bags(full, slower) == []  # PoseEstimate.wall_clock_fields
    assert [(d.index, d.field) for d in diff_bags(full, moved)] == [(2, "tool_from_object")]
    assert [(d.index, d.field) for d in diff_bags(dropped, moved)] == [
        (-1, "(count)"),
        (2, "tool_from_object"),
        (4, "(only in B)"),
    ]


class PlainRelay(Node):
    """A relay without parameters, to swap in for ``synthetic.relay``."""

    inputs = {"tick": Tick}
    outputs = {"tick": Tick}

    def on_tick(self, msg: Tick) -> None:
        self.io.publish("tick", msg)


def test_swapped_impl_drops_old_params_and_set_applies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    graph = build_replay_graph(GRAPH, bag, {"relay": f"{__name__}:PlainRelay"})
    assert graph["nodes"]["relay"]["params"] == {}
    code = cli_main(
        ["replay", str(bag), "--swap", "relay", "--set", "relay.add=7", "--print-graph"]
    )
    assert code == 0
    assert yaml.safe_load(capsys.readouterr().out)["nodes"]["relay"]["params"] == {"add": 7}


def test_exact_topics_selects_only_those() -> None:
    from runtime.bag import topic_filter

    chosen = topic_filter(exact_topics(["a/tick", "b.c/x"]))
    assert chosen("a/tick") and chosen("b.c/x")
    assert not any(chosen(t) for t in ("a/tick2", "xa/tick", "bxc/x", "a/tic"))
    assert topic_filter("camera")("left_camera/image")  # search, as --topics when recording


def test_recover_rewrites_a_cut_bag_with_a_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader

    from runtime.bag import BagReader

    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        w.add_run_info(graph_text="nodes: {}\n", command_line="launch.py g.yaml")
        for i in range(10):
            w.write_message("a/tick", Tick(header=Header(seq=i), value=float(i)), log_time_nanos=i)
            if i % 3 == 2:
                w.flush()
        w.set_runtime_drops({"a/tick": 4})
    with BagReader(path) as r:
        cut = r.chunks[-1].offset + 20  # the last chunk is lost
    path.write_bytes(path.read_bytes()[:cut])
    out = tmp_path / "fixed.mcap"
    assert cli_main(["bag", "recover", str(path), str(out)]) == 0
    assert "9 message(s) recovered" in capsys.readouterr().out
    with BagReader(out) as r:
        assert r.has_summary and not r.problems
        assert [m.decode().value for m in r.messages()] == [float(i) for i in range(9)]
        assert r.run_info()["command_line"] == "launch.py g.yaml"
        assert r.drops()["a/tick"]["runtime"] == 4
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == 9
    assert cli_main(["bag", "recover", str(out), str(out)]) == 2


LOOP = yaml.safe_load(
    """
nodes:
  source: {impl: synthetic.source}
  world: {impl: synthetic.merge, inputs: {a: source/tick, b: ctrl/tick}}
  cam: {impl: synthetic.relay, inputs: {tick: world/tick}}
  proc: {impl: synthetic.relay, inputs: {tick: cam/tick}}
  ctrl: {impl: synthetic.relay, inputs: {tick: proc/tick}}
  log: {impl: synthetic.sink, inputs: {tick: proc/tick}}
"""
)


def test_a_loop_back_into_the_replaced_node_stays_open(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bag = make_bag(
        tmp_path / "a.mcap",
        topics=("source/tick", "world/tick", "cam/tick", "proc/tick", "ctrl/tick"),
    )
    graph = build_replay_graph(LOOP, bag, {"proc": ""})
    # ctrl is downstream of proc but commands the world that the camera sees: replayed.
    assert set(graph["nodes"]) == {"proc", "log", "replay"}
    assert replay_params(graph)["topics"] == exact_topics(["cam/tick"])
    assert "ctrl is downstream of proc but feeds back" in caplog.text
    graph = build_replay_graph(LOOP, bag, {"proc": "", "ctrl": ""})
    assert set(graph["nodes"]) == {"proc", "ctrl", "log", "replay"}
    assert replay_params(graph)["topics"] == exact_topics(["cam/tick"])


def test_echo_skips_messages_it_cannot_decode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = bag_with_undecodable(tmp_path / "bad.mcap", 5, {1: "cut", 3: "cut"})
    assert cli_main(["bag", "echo", str(path), "--topic", "a/tick"]) == 1
    captured = capsys.readouterr()
    values = [line for line in captured.out.splitlines() if line.startswith("value:")]
    assert values == ["value: 0.0", "value: 2.0", "value: 4.0"]
    assert captured.out.count("SKIPPED, cannot decode: ") == 2
    assert "#1 Tick" in captured.out and "bad.mcap: topic a/tick: message at offset" in captured.out
    assert "2 message(s) could not be decoded" in captured.err
    assert cli_main(["bag", "echo", str(path), "--topic", "a/tick", "--strict"]) == 2
    captured = capsys.readouterr()
    assert captured.out.count("value:") == 1 and "bad.mcap: topic a/tick" in captured.err


def test_diff_counts_undecodable_messages_and_goes_on(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = bag_with_undecodable(tmp_path / "good.mcap", 5, {})
    bad = bag_with_undecodable(tmp_path / "bad.mcap", 5, {1: "cut"})
    diffs = diff_bags(good, bad)
    assert [(d.index, d.field) for d in diffs] == [(1, "(undecodable)")]
    assert "bad.mcap: topic a/tick" in diffs[0].detail
    assert cli_main(["bag", "diff", str(good), str(bad)]) == 1
    assert "1 difference(s) in 1 message(s)" in capsys.readouterr().out
    assert cli_main(["bag", "diff", str(good), str(bad), "--strict"]) == 2
    assert "bad.mcap: topic a/tick" in capsys.readouterr().err
    other = bag_with_undecodable(tmp_path / "other.mcap", 5, {})
    assert diff_bags(good, other) == []


def test_replay_strict_reaches_the_replay_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    assert cli_main(["replay", str(bag), "--replace", "sink", "--print-graph"]) == 0
    assert replay_params(yaml.safe_load(capsys.readouterr().out))["strict"] is False
    assert cli_main(["replay", str(bag), "--replace", "sink", "--strict", "--print-graph"]) == 0
    assert replay_params(yaml.safe_load(capsys.readouterr().out))["strict"] is True
