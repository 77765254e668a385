"""Lockstep replay of the shipped graphs: two replays of one recording, then ``bag diff``.

Each graph is recorded once per module (a few seconds of real node processes), then
replayed twice through the same swapped nodes with the README's command line; the two
output bags must not differ in any field but the wall-clock ones the message types
declare (``Message.wall_clock_fields``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.bag import BagReader
from runtime.bag.diff import diff_bags

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
