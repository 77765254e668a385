"""The tactile classifier's accuracy on a fresh held-out set, made and scored here.

A few minutes of the auto-labelling graph (``graphs/autolabel.yaml``) with fixed seeds no
training or earlier test set used (auto-labelling seed :data:`AUTOLABEL_SEED`, sensor noise
seed :data:`NOISE_SEED`) writes a small dataset; ``python -m perception.classify evaluate``
scores the committed model on it. The grasp accuracy (a grasp is right when the majority
of its frames is) is stated with its size and a 95% Wilson score interval, so a page that
quotes it says how much it can be trusted.

    python -m bench.heldout [--grasps 150] [--workdir out/report]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

MODEL = "models/tactile_resnet18.pt"
GRAPH = "graphs/autolabel.yaml"
AUTOLABEL_SEED = 101
NOISE_SEED = 102
GRASPS = 150
QUICK_GRASPS = 2
Z_95 = 1.959963984540054


def wilson_interval(correct: int, n: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``correct / n`` (``(0, 1)`` for n = 0)."""
    if n <= 0:
        return 0.0, 1.0
    if not 0 <= correct <= n:
        raise ValueError(f"correct must be in [0, {n}], got {correct}")
    p = correct / n
    denom = 1 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, center - half), min(1.0, center + half)


@dataclass(frozen=True)
class HeldOut:
    """What the held-out run measured, and the commands that reproduce it."""

    grasps: int
    correct: int
    frames: int
    frame_accuracy: float
    classes: list[str]
    make_command: str
    score_command: str
    secs: float

    @property
    def accuracy(self) -> float:
        return self.correct / self.grasps if self.grasps else float("nan")

    @property
    def interval(self) -> tuple[float, float]:
        return wilson_interval(self.correct, self.grasps)

    def summary(self) -> str:
        lo, hi = self.interval
        return (
            f"{self.correct}/{self.grasps} grasps right ({100 * self.accuracy:.2f}%, "
            f"95% Wilson interval {100 * lo:.2f}-{100 * hi:.2f}%), {self.frames} frames"
        )


def commands(grasps: int, dataset: str) -> tuple[list[str], list[str]]:
    """The argv (after ``python``) that makes the set and the one that scores it."""
    make = [
        "launch.py",
        GRAPH,
        *("--set", "world.rate_scale=3"),
        *("--set", f"world.seed={NOISE_SEED}"),
        *("--set", f"supervisor.seed={AUTOLABEL_SEED}"),
        *("--set", f"supervisor.grasps={grasps}"),
        *("--set", f"supervisor.dataset={dataset}"),
        *("--set", f"writer.dataset={dataset}"),
        *("--set", "writer.max_frames_per_grasp=6"),
    ]
    score = ["-m", "perception.classify", "evaluate", MODEL, dataset, "--json"]
    return make, score


def measure(grasps: int, *, workdir: Path, root: Path, timeout_secs: float = 3600) -> HeldOut:
    """Make a fresh ``grasps``-grasp set under ``workdir`` and score the committed model."""
    if grasps < 1:
        raise ValueError(f"grasps must be >= 1, got {grasps}")
    dataset = workdir / f"heldout_seed{AUTOLABEL_SEED}_{grasps}"
    if dataset.exists():
        shutil.rmtree(dataset)  # made fresh each time: a resumed set would not be this run's
    make, score = commands(grasps, str(dataset))
    start = time.perf_counter()
    for argv, what in ((make, "making the held-out set"), (score, "scoring the model")):
        proc = subprocess.run(
            [sys.executable, *argv], cwd=root, capture_output=True, text=True, timeout=timeout_secs
        )
        if proc.returncode != 0:
            tail = " / ".join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
            raise RuntimeError(f"{what} failed (exit code {proc.returncode}): {tail}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    n = int(result["grasps"])
    shown = str(dataset.relative_to(root)) if dataset.is_relative_to(root) else str(dataset)
    make_shown, score_shown = commands(grasps, shown)
    return HeldOut(
        grasps=n,
        correct=int(round(float(result["grasp_accuracy"]) * n)),
        frames=int(result["frames"]),
        frame_accuracy=float(result["accuracy"]),
        classes=list(result["classes"]),
        make_command="python " + " ".join(make_shown),
        score_command="python " + " ".join(score_shown[:-1]),
        secs=time.perf_counter() - start,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.heldout", description=__doc__)
    parser.add_argument("--grasps", type=int, default=GRASPS)
    parser.add_argument("--workdir", type=Path, default=Path("out/report"))
    args = parser.parse_args(argv)
    root = Path(__file__).resolve().parents[1]
    print(measure(args.grasps, workdir=args.workdir.resolve(), root=root).summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
