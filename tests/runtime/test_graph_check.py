"""The graph checker: every error names the file, the node and the field; nothing starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import nodes.recorder  # noqa: F401 - registers the recorder
from messages.errors import GraphError
from runtime import graph as graphs
from runtime.registry import known
from tests.synthetic_nodes import IMPLS  # registers the synthetic nodes too

ROOT = Path(__file__).resolve().parents[2]
PRESSURE = "tests.runtime.nodes_for_tests:PressureSource"


def check_text(text: str, tmp_path: Path) -> graphs.Graph:
    path = tmp_path / "g.yaml"
    path.write_text(text)
    return graphs.load(path)


def errors_of(text: str, tmp_path: Path) -> str:
    with pytest.raises(GraphError) as info:
        check_text(text, tmp_path)
    return str(info.value)


def test_valid_graph_resolves_edges_and_types(tmp_path: Path) -> None:
    g = check_text(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: {from: src/tick, policy: latest}}}\n",
        tmp_path,
    )
    assert g.edges() == [("src/tick", "sink", "tick")]
    assert g.nodes["sink"].inputs["tick"].policy == "latest"
    assert g.nodes["src"].params.rate_hz == 20.0


def test_barrier_topics_are_those_that_reach_a_fan_in(tmp_path: Path) -> None:
    g = check_text(
        "nodes:\n"
        "  a: {impl: synthetic.source}\n"
        "  b: {impl: synthetic.source}\n"
        "  c: {impl: synthetic.source}\n"
        "  relay: {impl: synthetic.relay, inputs: {tick: a/tick}}\n"
        # one publisher (relay) on both inputs: its order holds, not a fan-in
        "  same: {impl: synthetic.merge, inputs: {a: relay/tick, b: relay/tick}}\n"
        # two publishers: a fan-in, so a/tick (through relay) and b/tick are barriers
        "  fan: {impl: synthetic.merge, inputs: {a: relay/tick, b: b/tick}}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: fan/tick}}\n"
        "  rec: {impl: recorder, params: {path: x.mcap}, inputs: {t0: same/tick, t1: c/tick}}\n",
        tmp_path,
    )
    # The recorder merges in any order: c/tick reaches only it.
    assert g.barrier_topics() == {"a/tick", "relay/tick", "b/tick"}


def test_unknown_implementation_lists_valid_ones(tmp_path: Path) -> None:
    err = errors_of("nodes:\n  a: {impl: no.such}\n", tmp_path)
    assert "g.yaml: node 'a'.impl" in err and "synthetic.source" in err
    assert "synthetic.source" in known()


def test_unknown_output_and_unknown_node(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: src/tock, other: ghost/tick}}\n",
        tmp_path,
    )
    assert "node 'sink'.inputs.tick: node 'src' has no output 'tock'" in err
    assert "node 'sink'.inputs.other: no node publishes 'ghost/tick'" in err


def test_type_mismatch_names_both_types(tmp_path: Path) -> None:
    err = errors_of(
        f"nodes:\n  p: {{impl: '{PRESSURE}'}}\n  sink: {{impl: synthetic.sink, inputs: {{tick: p/pressure}}}}\n",
        tmp_path,
    )
    assert "node 'sink'.inputs.tick: type mismatch" in err and "Pressure" in err and "Tick" in err


def test_missing_required_input(tmp_path: Path) -> None:
    err = errors_of("nodes:\n  sink: {impl: synthetic.sink}\n", tmp_path)
    assert "node 'sink'.inputs.tick: required input is not connected" in err
    assert "other" not in err  # optional


def test_unknown_and_ill_typed_params(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n  a: {impl: synthetic.source, params: {rate: 3}}\n"
        "  b: {impl: synthetic.source, params: {rate_hz: fast}}\n"
        "  c: {impl: synthetic.source, params: {rate_hz: -3}}\n",
        tmp_path,
    )
    assert "node 'a'.params: unknown parameter(s) ['rate']" in err
    assert "node 'b'.params" in err and "rate_hz" in err
    assert "node 'c'.params: rate_hz must be > 0, got -3" in err


def test_duplicate_node_names_and_yaml_errors(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n  a: {impl: synthetic.source}\n  a: {impl: synthetic.source}\n", tmp_path
    )
    assert "duplicate key 'a'" in err and "g.yaml" in err
    err = errors_of("nodes:\n  a: {impl: synthetic.source\n", tmp_path)
    assert "g.yaml: YAML error" in err


def test_bad_policy_restart_and_keys(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n  src: {impl: synthetic.source, restart: sometimes, colour: red}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: {from: src/tick, policy: newest, queue_size: 0}}}\n",
        tmp_path,
    )
    assert "node 'src'.restart.policy" in err
    assert "node 'src': unknown key 'colour'" in err
    assert "node 'sink'.inputs.tick.policy" in err
    assert "node 'sink'.inputs.tick.queue_size" in err


def test_overrides_set_swap_only(tmp_path: Path) -> None:
    doc = {
        "nodes": {
            "src": {"impl": "synthetic.source"},
            "relay": {"impl": "synthetic.relay", "inputs": {"tick": "src/tick"}},
            "sink": {
                "impl": "synthetic.sink",
                "inputs": {"tick": "relay/tick", "other": "src/tick"},
            },
        }
    }
    out = graphs.apply_overrides(
        doc, sets=["src.rate_hz=5", "relay.add=2.5"], swaps=["relay=synthetic.merge"]
    )
    assert out["nodes"]["src"]["params"]["rate_hz"] == 5
    assert out["nodes"]["relay"]["impl"] == "synthetic.merge"
    assert doc["nodes"]["relay"]["impl"] == "synthetic.relay"  # the original is untouched
    with pytest.raises(
        GraphError, match="relay"
    ):  # merge has no 'tick' input, and 'add' is unknown
        graphs.check(out, source="x.yaml")
    only = graphs.apply_overrides(doc, only=["src", "sink"])
    assert set(only["nodes"]) == {"src", "sink"} and only["nodes"]["sink"]["inputs"] == {
        "other": "src/tick"
    }
    with pytest.raises(GraphError, match="--set"):
        graphs.apply_overrides(doc, sets=["nonode.x=1"])


def test_check_command_starts_nothing_and_exits_2(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        # launch.py registers only production nodes: the test nodes by module:Class.
        f"nodes:\n  sink: {{impl: '{IMPLS['synthetic.sink']}'}}\n"
        f"  src: {{impl: '{IMPLS['synthetic.source']}', params: {{count: -1}}}}\n"
    )
    proc = subprocess.run(
        [sys.executable, "launch.py", str(path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "bad.yaml: node 'sink'.inputs.tick" in proc.stderr
    assert "bad.yaml: node 'src'.params: count must be >= 0" in proc.stderr
    assert "starting" not in proc.stdout
    ok = subprocess.run(
        [sys.executable, "launch.py", "graph.yaml", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0 and "OK" in ok.stdout
