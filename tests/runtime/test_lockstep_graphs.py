"""Lockstep replay of the shipped graphs: two replays of one recording, then ``bag diff``.

Each graph is recorded once per module (a few seconds of real node processes), then
replayed twice through the same swapped nodes with ``launch.py replay ... --lockstep
--record``; the two output bags must not differ in any field but the wall-clock ones the
message types declare (``Message.wall_clock_fields``).

Which nodes: every node a replay can rerun, that is one with inputs that is not
``clocked`` (a simulated world or a device driver follows the clock, not the bag; the
replay says so, tested below). Which implementations: each such node's own, and every
other registered one of its family (``pose_estimator.*``) that the graph check accepts
in its place. To keep it affordable each graph takes a few rounds, not one per node:
round 0 reruns every such node at once with its own implementation (the whole pipeline
downstream of the world, live in lockstep), round k the nodes that have a k-th
implementation, swapped to it. ``graphs/hardware.yaml`` is recorded on the emulated
devices (``--emulate``). The two replays of a case run at the same time.
"""

from __future__ import annotations

import copy
import functools
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

import nodes  # noqa: F401  (the index of the node implementations)
from messages.errors import GraphError
from runtime.bag import BagReader
from runtime.bag.diff import diff_bags
from runtime.graph import check
from runtime.params import field_names
from runtime.registry import known, resolve
from runtime.replaygraph import ReplayOptions, build_replay_graph
from sim.rig_launch import DEVICE_IMPLS
from tests import launching

ROOT = Path(__file__).resolve().parents[2]


launch_py = functools.partial(launching.launch_py, timeout=300)


def replay_twice(bag: Path, out: Path, *swaps: str) -> tuple[Path, Path]:
    """Two lockstep replays of ``bag`` through ``swaps`` (``NODE=IMPL``), recorded, run at
    the same time (each loads the machine for the other)."""
    flags = [f for swap in swaps for f in ("--swap", swap)]
    paths = [out / "a.mcap", out / "b.mcap"]
    runs = [["replay", bag, *flags, "--lockstep", "--record", p] for p in paths]
    for done in launching.launch_py_together(*runs, timeout=300):
        assert done.returncode == 0, done.stdout + done.stderr
    return paths[0], paths[1]


def counts(path: Path) -> dict[str, int]:
    with BagReader(path) as reader:
        return {topic: s.messages for topic, s in reader.stats().items()}


@pytest.fixture(scope="module")
def default_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default graph (the simulated handover), recorded once."""
    path = tmp_path_factory.mktemp("default") / "run.mcap"
    done = launch_py("graph.yaml", "--record", path)
    assert done.returncode == 0, done.stdout + done.stderr
    return path


@pytest.mark.parametrize("impl", ["pose_estimator.icp", "pose_estimator.lm"])
def test_the_readme_replay_through_a_pose_solver_is_the_same_twice(
    default_run: Path, tmp_path: Path, impl: str
) -> None:
    a, b = replay_twice(default_run, tmp_path, f"pose={impl}")
    assert diff_bags(a, b) == []
    # Every contact patch the bag holds is answered, not the ones a timer happened to see.
    assert counts(a)["pose/pose"] == counts(default_run)["contact_patch/patch"]


# -- every graph, every node a replay can rerun, every implementation ------------------------

RECORD_SECS = "2.5"
# What keeps a graph's run short, or out of the repository (its dataset folders).
SETS: dict[str, Callable[[Path], list[str]]] = {
    "autolabel": lambda tmp: [
        "supervisor.grasps=1",
        f"supervisor.dataset={tmp / 'data'}",
        f"writer.dataset={tmp / 'data'}",
    ],
    "dish_loading": lambda tmp: ["supervisor.objects=1"],
}
# A graph with a hosts table replays graph.yaml's recording (the same nodes) on this
# machine (--no-hosts); tests/hosts replays across hosts in lockstep.
RECORDED_AS = {"handover_hosts": "graph"}
# The hardware graph is recorded on the emulated devices (their drivers are clocked: the
# replay stands in for them). MuJoCo's world records on a coarse mesh: a replay has no
# world to set it on.
RECORD_FLAGS = {
    "hardware": ["--emulate"],
    "mujoco_fill": ["--set", "world.mesh_spacing_m=0.016"],
}


def graph_files() -> dict[str, Path]:
    files = {p.stem: p for p in sorted((ROOT / "graphs").glob("*.yaml"))}
    return {"graph": ROOT / "graph.yaml", **files}


def alternatives(doc: dict[str, Any], node: str) -> list[str]:
    """The registered implementations of ``node``'s family the graph check accepts there."""
    own = doc["nodes"][node]["impl"]
    family = own.split(".")[0] + "."
    found = []
    for impl in known():
        if impl == own or not impl.startswith(family) or resolve(impl).clocked:
            continue
        trial = copy.deepcopy(doc)
        body = trial["nodes"][node]
        body["impl"] = impl
        fields = set(field_names(resolve(impl).Params))
        body["params"] = {k: v for k, v in (body.get("params") or {}).items() if k in fields}
        try:
            check(trial)
        except GraphError:
            continue
        found.append(impl)
    return found


def rounds(path: Path) -> list[list[str]]:
    """The ``--swap`` values of each round (module docstring)."""
    doc = yaml.safe_load(path.read_text())
    checked = check(doc, source=str(path))
    rerun = {
        name: [spec.impl, *alternatives(doc, name)]
        for name, spec in checked.nodes.items()
        if spec.cls.inputs and not spec.cls.clocked and not spec.cls.raw_input
    }
    depth = max(len(impls) for impls in rerun.values())
    out = [[name for name in rerun]]
    for k in range(1, depth):
        out.append([f"{name}={impls[k]}" for name, impls in rerun.items() if len(impls) > k])
    return out


CASES = [
    pytest.param(name, k, swaps, id=f"{name}-round{k}")
    for name, path in graph_files().items()
    for k, swaps in enumerate(rounds(path))
]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """Each graph recorded once (for RECORD_SECS at most), on first use."""
    done: dict[str, Path] = {}

    def record(name: str) -> Path:
        name = RECORDED_AS.get(name, name)
        if name not in done:
            tmp = tmp_path_factory.mktemp(f"rec-{name}")
            sets = [f for value in SETS.get(name, lambda _: [])(tmp) for f in ("--set", value)]
            path = tmp / "run.mcap"
            flags = RECORD_FLAGS.get(name, [])
            run = launch_py(
                graph_files()[name], *flags, "--record", path, "--duration", RECORD_SECS, *sets
            )
            # A task's verdict may be non-zero (a dropped object); the recording stands.
            assert path.exists() and "Traceback" not in run.stdout + run.stderr, run.stdout
            done[name] = path
        return done[name]

    return record


# Round 0 reruns a whole pipeline twice: minutes on a loaded two-core machine.
@pytest.mark.timeout(900)
@pytest.mark.parametrize(("name", "k", "swaps"), CASES)
def test_two_lockstep_replays_of_every_graph_are_the_same(
    recordings: Callable[[str], Path], tmp_path: Path, name: str, k: int, swaps: list[str]
) -> None:
    bag = recordings(name)
    extra: list[str | Path] = []
    if name in RECORDED_AS:
        extra = ["--graph", graph_files()[name], "--no-hosts"]
    flags = [f for swap in swaps for f in ("--swap", swap)]
    outputs = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    runs = []
    for out in outputs:
        # Each replay its own dataset folder: a writer that finds one resumes from it.
        tmp = tmp_path / out.stem
        sets = [f for v in SETS.get(name, lambda _: [])(tmp) for f in ("--set", v)]
        runs.append(["replay", bag, *extra, *flags, "--lockstep", "--record", out, *sets])
    for done, out in zip(launching.launch_py_together(*runs, timeout=600), outputs, strict=True):
        assert out.exists(), done.stdout + done.stderr
        assert "Traceback" not in done.stdout + done.stderr, done.stdout + done.stderr
    diffs = diff_bags(*outputs)
    assert diffs == [], "\n".join(map(str, diffs[:20]))
    assert sum(counts(outputs[0]).values()) > 0


def test_the_hardware_graph_replays_without_its_devices() -> None:
    # Its drivers follow their devices (clocked): the replay stands in for them.
    rerun = {n for swaps in rounds(graph_files()["hardware"]) for n in swaps}
    doc = yaml.safe_load(graph_files()["hardware"].read_text())
    drivers = {n for n, body in doc["nodes"].items() if body["impl"] in DEVICE_IMPLS}
    assert drivers == {"gripper", "left_camera", "right_camera", "left_pressure", "right_pressure"}
    assert not {n.split("=")[0] for n in rerun} & drivers


def test_a_replay_that_reruns_a_clocked_node_says_lockstep_cannot_hold(
    default_run: Path, caplog: pytest.LogCaptureFixture
) -> None:
    graph = yaml.safe_load((ROOT / "graph.yaml").read_text())
    with caplog.at_level(logging.WARNING):
        build_replay_graph(graph, default_run, {"world": ""}, ReplayOptions(lockstep=True))
    assert "world (world.sim) follows the clock or a device, not the bag" in caplog.text
