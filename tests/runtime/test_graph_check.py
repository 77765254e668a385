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
NESTED = "tests.runtime.nodes_for_tests:NestedNode"


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
    assert "g.yaml: node 'a'.params.rate: is unknown; SourceParams takes rate_hz," in err
    assert "g.yaml: node 'a'.params.rate: is unknown" in err and err.count(", got 3") == 1
    assert "g.yaml: node 'b'.params.rate_hz: must be a number, got 'fast'" in err
    assert "g.yaml: node 'c'.params.rate_hz: must be > 0, got -3" in err


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
    assert "bad.yaml: node 'src'.params.count: must be >= 0, got -1" in proc.stderr
    assert "starting" not in proc.stdout
    ok = subprocess.run(
        [sys.executable, "launch.py", "graph.yaml", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0 and "OK" in ok.stdout


# -- one walk ---------------------------------------------------------------------------------


def test_graph_knows_producers_consumers_and_reachability(tmp_path: Path) -> None:
    g = check_text(
        "nodes:\n"
        "  a: {impl: synthetic.source}\n"
        "  b: {impl: synthetic.source}\n"
        "  relay: {impl: synthetic.relay, inputs: {tick: a/tick}}\n"
        "  fan: {impl: synthetic.merge, inputs: {a: relay/tick, b: b/tick}}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: fan/tick, other: a/tick}}\n",
        tmp_path,
    )
    assert g.producers == {
        "a/tick": "a",
        "b/tick": "b",
        "relay/tick": "relay",
        "fan/tick": "fan",
    }
    assert sorted(g.consumers["a/tick"]) == [("relay", "tick"), ("sink", "other")]
    assert g.feeds["a"] == {"relay", "sink"} and g.fed_by["fan"] == {"relay", "b"}
    assert g.downstream({"relay"}) == {"relay", "fan", "sink"}
    assert g.upstream({"fan"}) == {"fan", "relay", "a", "b"}
    assert g.downstream({"a"}, skip={"fan"}) == {"a", "relay", "sink"}


# -- root causes only ----------------------------------------------------------------------------


def test_a_node_that_fails_its_own_check_is_its_only_error(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        f"  pose: {{impl: '{NESTED}', params: {{tol: -1.0}}, inputs: {{tick: src/tick}}}}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: pose/tick}}\n"
        "  ghost: {impl: no.such, inputs: {x: src/tick}}\n"
        "  late: {impl: synthetic.sink, inputs: {tick: ghost/out}}\n",
        tmp_path,
    )
    lines = err.splitlines()
    assert len(lines) == 2, err
    assert lines[0].endswith("g.yaml: node 'pose'.params.tol: must be > 0, got -1.0")
    assert "node 'ghost'.impl: unknown implementation 'no.such'" in lines[1]
    assert "no node publishes" not in err and "pose/tick" not in err


def test_edge_errors_still_name_a_missing_node_or_output(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: src/tock, other: gone/tick}}\n",
        tmp_path,
    )
    assert "node 'sink'.inputs.tick: node 'src' has no output 'tock'" in err
    assert "node 'sink'.inputs.other: no node publishes 'gone/tick'" in err


# -- one error style for parameters --------------------------------------------------------------


def test_param_errors_name_node_field_value_and_what_is_allowed(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        f"  a: {{impl: '{NESTED}', params: {{inner: {{winsize: 2}}}}, inputs: {{tick: src/tick}}}}\n"
        f"  b: {{impl: '{NESTED}', params: {{inner: {{winsize: 2.5}}}}, inputs: {{tick: src/tick}}}}\n"
        f"  c: {{impl: '{NESTED}', params: {{inner: {{size: 3}}}}, inputs: {{tick: src/tick}}}}\n"
        f"  d: {{impl: '{NESTED}', params: {{inner: 7}}, inputs: {{tick: src/tick}}}}\n"
        "  e: {impl: synthetic.source, params: {count: many}}\n",
        tmp_path,
    )
    assert "g.yaml: node 'a'.params.inner.winsize: must be in [3, 201], got 2" in err
    assert "g.yaml: node 'b'.params.inner.winsize: must be an integer, got 2.5" in err
    assert "g.yaml: node 'c'.params.inner.size: is unknown; InnerParams takes winsize, got 3" in err
    assert "g.yaml: node 'd'.params.inner: must be a mapping, got 7" in err
    assert "g.yaml: node 'e'.params.count: must be an integer, got 'many'" in err
    assert "Expected" not in err and "$." not in err  # msgspec's own wording is rewritten


def test_restart_and_input_errors_share_the_style(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  src: {impl: synthetic.source, restart: {policy: on-failure, backoff_secs: -1}}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: {from: src/tick, policy: newest}}}\n",
        tmp_path,
    )
    assert "node 'src'.restart.backoff_secs: must be >= 0, got -1" in err
    assert "node 'sink'.inputs.tick.policy: must be one of ('queue', 'latest'), got 'newest'" in err


# -- --set reaches nested parameters -------------------------------------------------------------


def test_set_takes_a_dotted_path_into_nested_params(tmp_path: Path) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(
        "nodes:\n"
        "  src: {impl: synthetic.source}\n"
        f"  shear: {{impl: '{NESTED}', inputs: {{tick: src/tick}}}}\n"
    )
    g = graphs.load(path, sets=["shear.inner.winsize=45", "shear.tol=0.001"])
    assert g.nodes["shear"].params.inner.winsize == 45
    assert g.nodes["shear"].params.tol == 0.001
    assert g.nodes["shear"].raw_params == {"inner": {"winsize": 45}, "tol": 0.001}
    with pytest.raises(GraphError, match=r"node 'shear'\.params\.inner\.winsize: must be in"):
        graphs.load(path, sets=["shear.inner.winsize=2"])
    with pytest.raises(GraphError, match=r"node 'shear'\.params\.inner\.nope: is unknown"):
        graphs.load(path, sets=["shear.inner.nope=2"])
    with pytest.raises(GraphError, match=r"shear\.params\.tol is not a mapping"):
        graphs.load(path, sets=["shear.tol=1", "shear.tol.x=2"])
    with pytest.raises(GraphError, match="PARAM may be a dotted path"):
        graphs.load(path, sets=["shear.inner..winsize=2"])


# -- --check catches what would fail at start ----------------------------------------------------


def test_host_must_be_a_loopback_address_bindable_here(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  a: {impl: synthetic.source, host: '127.0.0.1:5555'}\n"
        "  b: {impl: synthetic.source, host: no-such-host.invalid}\n"
        "  c: {impl: synthetic.source, host: 192.0.2.1}\n"
        "  d: {impl: synthetic.source, host: 'tcp://127.0.0.1'}\n"
        "  e: {impl: synthetic.source, host: 3}\n"
        "  f: {impl: synthetic.source, host: 0.0.0.0}\n"
        "  ok: {impl: synthetic.source, host: 127.0.0.1}\n"
        "  lo: {impl: synthetic.source, host: localhost}\n",
        tmp_path,
    )
    for name in "abcde":
        assert f"g.yaml: node '{name}'.host: must be an address or interface of this machine" in err
    assert "g.yaml: node 'f'.host: must be a loopback address (127.0.0.1), got '0.0.0.0'" in err
    assert "'ok'" not in err and "'lo'" not in err


def test_queue_size_must_fit_a_socket_high_water_mark(tmp_path: Path) -> None:
    text = (
        "nodes:\n  src: {impl: synthetic.source}\n"
        "  sink: {impl: synthetic.sink, inputs: {tick: {from: src/tick, queue_size: %d}}}\n"
    )
    err = errors_of(text % 2**31, tmp_path)
    assert f"node 'sink'.inputs.tick.queue_size: must be an integer in [1, {2**31 - 1}]" in err
    assert check_text(text % (2**31 - 1), tmp_path).nodes["sink"].inputs["tick"].queue_size


def test_a_name_too_long_for_its_socket_path_is_refused(tmp_path: Path) -> None:
    long = "n" * 120
    err = errors_of(f"nodes:\n  {long}: {{impl: synthetic.source}}\n", tmp_path)
    assert f"node '{long}': the name is too long for its socket path" in err
    assert "bytes, the OS allows 107" in err
    # on tcp there is no socket path
    check_text(f"nodes:\n  {long}: {{impl: synthetic.source, host: 127.0.0.1}}\n", tmp_path)


def test_nan_and_inf_are_refused_anywhere(tmp_path: Path) -> None:
    err = errors_of(
        "nodes:\n"
        "  a: {impl: synthetic.source, hang_timeout_secs: .nan}\n"
        "  b: {impl: synthetic.source, params: {rate_hz: .inf}}\n"
        f"  c: {{impl: '{NESTED}', params: {{tol: .nan}}, inputs: {{tick: a/tick}}}}\n"
        "  d: {impl: synthetic.source, restart: {policy: on-failure, backoff_max_secs: .inf}}\n"
        "  e: {impl: synthetic.sink, inputs: {tick: a/tick}, hang_timeout_secs: -.inf}\n",
        tmp_path,
    )
    assert "node 'a'.hang_timeout_secs: must be a finite number > 0, got nan" in err
    assert "node 'b'.params.rate_hz: must be a finite number, got inf" in err
    assert "node 'c'.params.tol: must be a finite number, got nan" in err
    assert "node 'd'.restart.backoff_max_secs: must be a finite number, got inf" in err
    assert "node 'e'.hang_timeout_secs: must be a finite number > 0, got -inf" in err


def test_node_names_with_newlines_or_odd_characters_are_refused(tmp_path: Path) -> None:
    err = errors_of(
        'nodes:\n  "a\\n": {impl: synthetic.source}\n  "b c": {impl: synthetic.source}\n'
        '  "../x": {impl: synthetic.source}\n  7: {impl: synthetic.source}\n',
        tmp_path,
    )
    for name in ("'a\\n'", "'b c'", "'../x'", "7"):
        assert f"node {name}: a node name must be a letter or '_'" in err


def test_a_declared_file_must_exist_and_be_a_file(tmp_path: Path) -> None:
    text = (
        "nodes:\n  src: {impl: synthetic.source}\n"
        f"  net: {{impl: '{NESTED}', params: {{model: %s}}, inputs: {{tick: src/tick}}}}\n"
    )
    err = errors_of(text % "models/none.pt", tmp_path)
    assert (
        "node 'net'.params.model: must name an existing file (no such file), got 'models/none.pt'"
        in err
    )
    err = errors_of(text % str(tmp_path), tmp_path)
    assert "node 'net'.params.model: must name a file (it is a directory" in err
    model = tmp_path / "net.pt"
    model.write_bytes(b"x")
    assert check_text(text % model, tmp_path).nodes["net"].params.model == str(model)


def test_the_classifier_model_and_the_world_scene_are_checked_before_start(
    tmp_path: Path,
) -> None:
    import nodes.classifier  # noqa: F401 - registers classifier.resnet18
    import nodes.world  # noqa: F401 - registers world.sim

    err = errors_of(
        "nodes:\n"
        "  world: {impl: world.sim, params: {scene: scenes/none.yaml}}\n"
        "  classifier: {impl: classifier.resnet18, params: {model: models/none.pt}}\n",
        tmp_path,
    )
    assert "node 'world'.params.scene: " in err and "scenes/none.yaml" in err
    assert "node 'classifier'.params.model: must name an existing file" in err
    assert "inputs" not in err  # the failed nodes' edges are not reported again


def test_check_imports_only_the_modules_the_graph_names(tmp_path: Path) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(
        f"nodes:\n  p: {{impl: '{PRESSURE}'}}\n"
        "  sink: {impl: 'tests.synthetic_nodes:SyntheticSink', inputs: {tick: src/tick}}\n"
        "  src: {impl: 'tests.synthetic_nodes:SyntheticSource'}\n"
    )
    code = (
        "import sys; from runtime import graph; graph.load(sys.argv[1]); "
        "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('nodes', 'tests', 'torch', 'casadi', 'cv2', 'perception', 'sim', 'scipy'))))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    # The graph's own modules (test nodes here), no production node, no heavy library.
    assert proc.stdout.split() == [
        "tests",
        "tests.runtime",
        "tests.runtime.nodes_for_tests",
        "tests.synthetic_nodes",
    ]


def test_every_registered_implementation_reports_bad_params_in_the_one_style() -> None:
    import nodes
    from runtime.params import ParamError, build_params, describe
    from runtime.registry import resolve

    nodes.import_all()
    checked = 0
    for impl in known():
        params_cls = resolve(impl).Params
        for info in describe(params_cls):
            if info.type not in ("int", "float", "int | None", "float | None"):
                continue
            values: dict = {}
            inner = values
            *parents, leaf = info.path.split(".")
            for key in parents:
                inner = inner.setdefault(key, {})
            inner[leaf] = -(10**9)
            try:
                build_params(params_cls, values)
            except ParamError as err:
                text = str(err)
                assert "Expected" not in text and "$." not in text, (impl, text)
                assert ", got " in text or err.rule.startswith("is required"), (impl, text)
                checked += 1
    assert checked > 50


def test_every_parameter_class_is_a_declared_struct_that_refuses_unknown_fields() -> None:
    import inspect

    import msgspec.inspect as mi

    import nodes

    nodes.import_all()
    seen: dict[type, mi.Type] = {}

    def walk(t: mi.Type) -> None:
        if isinstance(t, mi.Metadata):
            walk(t.type)
        elif isinstance(t, mi.UnionType):
            for member in t.types:
                walk(member)
        elif isinstance(t, mi.StructType | mi.DataclassType):
            seen[t.cls] = t
            for f in t.fields:
                walk(f.type)

    for impl in known():
        walk(mi.type_info(graphs.resolve(impl).Params))
    loose = sorted(
        cls.__qualname__
        for cls, t in seen.items()
        if not (
            isinstance(t, mi.StructType)
            and t.forbid_unknown_fields
            and cls.__struct_config__.frozen
            and all(p.kind is p.KEYWORD_ONLY for p in inspect.signature(cls).parameters.values())
        )
    )
    assert len(seen) > 30 and loose == []


@pytest.mark.parametrize(
    "values, line",
    [
        ({"method": 5}, "params.method: must be one of ('farneback',), got 5"),
        ({"farneback": {"poly_n": 6}}, "params.farneback.poly_n: must be one of (5, 7), got 6"),
        ({"dis": {"patch_size": 1}}, "params.dis.patch_size: must be >= 2, got 1"),
        (
            {"dis": {"patch_size": "a"}},
            "params.dis.patch_size: must be an integer or null, got 'a'",
        ),
        ({"farneback": {"pyr_scale": 1}}, "params.farneback.pyr_scale: must be in (0, 1), got 1"),
        ({"max_depth_m": 0.0}, "params.max_depth_m: must be > min_depth_m (0.01), got 0.0"),
    ],
)
def test_declared_choices_and_limits_read_in_the_one_style(values: dict, line: str) -> None:
    from nodes.shear_tracker import FarnebackTrackerParams
    from runtime.params import ParamError, build_params

    with pytest.raises(ParamError) as info:
        build_params(FarnebackTrackerParams, values)
    assert info.value.line() == line
