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
implementation, swapped to it. ``graphs/hardware.yaml`` needs the devices:
``graphs/handover_wsg50.yaml`` (the gripper driver against the world's WSG 50 emulator)
stands in for it.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
import subprocess
import sys
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
from runtime.registry import known, resolve
from runtime.replaygraph import ReplayOptions, build_replay_graph

ROOT = Path(__file__).resolve().parents[2]


def launch_py(*args: str | Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, str(ROOT / "launch.py"), *map(str, args)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def replay_twice(bag: Path, out: Path, *swaps: str) -> tuple[Path, Path]:
    """Two lockstep replays of ``bag`` through ``swaps`` (``NODE=IMPL``), recorded."""
    outputs = []
    for run in ("a", "b"):
        path = out / f"{run}.mcap"
        flags = [f for swap in swaps for f in ("--swap", swap)]
        done = launch_py("replay", bag, *flags, "--lockstep", "--record", path)
        assert done.returncode == 0, done.stdout + done.stderr
        outputs.append(path)
    return outputs[0], outputs[1]


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
NOT_RUNNABLE = {"hardware": "needs the real devices; graphs/handover_wsg50.yaml stands in"}


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
        fields = {f.name for f in dataclasses.fields(resolve(impl).Params)}
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


# Whole pipelines rerun in lockstep that still differ between two replays (not fixed yet):
# the shear tracker's output in these, near the release; every other case holds.
OPEN = {
    ("handover_wsg50", 0): "shear flow and overlay differ slightly between two replays",
    ("stacking", 0): "the shear tracker's reference differs at the release",
}
CASES = [
    pytest.param(
        name,
        k,
        swaps,
        id=f"{name}-round{k}",
        marks=[pytest.mark.xfail(reason=OPEN[name, k], strict=False)] if (name, k) in OPEN else [],
    )
    for name, path in graph_files().items()
    if name not in NOT_RUNNABLE
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
            run = launch_py(graph_files()[name], "--record", path, "--duration", RECORD_SECS, *sets)
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
    outputs = []
    for run in ("a", "b"):
        # Each replay its own dataset folder: a writer that finds one resumes from it.
        sets = [f for v in SETS.get(name, lambda _: [])(tmp_path / run) for f in ("--set", v)]
        out = tmp_path / f"{run}.mcap"
        flags = [f for swap in swaps for f in ("--swap", swap)]
        done = launch_py("replay", bag, *extra, *flags, "--lockstep", "--record", out, *sets)
        assert out.exists(), done.stdout + done.stderr
        assert "Traceback" not in done.stdout + done.stderr, done.stdout + done.stderr
        outputs.append(out)
    diffs = diff_bags(*outputs)
    assert diffs == [], "\n".join(map(str, diffs[:20]))
    assert sum(counts(outputs[0]).values()) > 0


def test_hardware_graph_is_listed_as_not_runnable_here() -> None:
    # Keep this list honest: the hardware graph is the only one left out.
    assert set(NOT_RUNNABLE) == {"hardware"} and "hardware" in graph_files()


def test_a_replay_that_reruns_a_clocked_node_says_lockstep_cannot_hold(
    default_run: Path, caplog: pytest.LogCaptureFixture
) -> None:
    graph = yaml.safe_load((ROOT / "graph.yaml").read_text())
    with caplog.at_level(logging.WARNING):
        build_replay_graph(graph, default_run, {"world": ""}, ReplayOptions(lockstep=True))
    assert "world (world.sim) follows the clock or a device, not the bag" in caplog.text
