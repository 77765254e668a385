"""Batch work on Ray against a plain loop: replays, auto-labelling, training processes.

python -m bench.batch [--json] [--quick]

Rows, each measured side by side in one run on this machine:

- ``replay``: the same recordings of the default graph replayed in lockstep through
  ``pose_estimator.lm`` (``launch.py batch replay``'s task), one after another in this
  process (``loop``), then on a local Ray with 1 and 2 workers: recordings per minute,
  the Ray start included (``ray start`` is its own row);
- ``autolabel``: worlds of the auto-labelling graph (one seed each), likewise: grasps
  per minute;
- ``train``: ``perception.classify train`` alone and under ``torchrun --nproc-per-node
  2`` on the same toy dataset: training samples per second (median over the epochs
  after the first).

A graph is many processes: on two cores a replay already keeps both busy much of the
time, so two workers cannot double the rate here (docs/batch.md works the cluster case
out from these figures). ``--quick`` (the smoke test) uses one short recording, one world
of one grasp and a tiny network: it shows every row is measured, not what parallel work
gains.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import Row, main, median
from cli import batchjobs
from cli.batch import run_tasks

ROOT = batchjobs.ROOT
SWAP = ["pose=pose_estimator.lm"]


def _record(out: Path, secs: float) -> Path:
    command = [sys.executable, str(ROOT / "launch.py"), str(ROOT / "graph.yaml")]
    command += ["--duration", str(secs), "--record", str(out), "--log-level", "WARNING"]
    subprocess.run(command, cwd=ROOT, check=True, capture_output=True, stdin=subprocess.DEVNULL)
    return out


def _timed(job, calls, *, use_ray: bool, workers: int) -> tuple[float, list[dict]]:
    start = time.monotonic()
    rows = run_tasks(
        job, calls, [str(c[0]) for c in calls], address=None, workers=workers, use_ray=use_ray
    )
    if not all(r.get("status") == "ok" for r in rows):
        raise RuntimeError(f"bench.batch: a task failed: {rows}")
    return time.monotonic() - start, rows


MODES = (("loop", False, 1), ("ray", True, 1), ("ray", True, 2))


def _replay_rows(work: Path, quick: bool) -> list[Row]:
    count, secs = (1, 1.0) if quick else (4, 3.0)
    bags = [_record(work / f"run{i}.mcap", secs) for i in range(count)]
    rows: list[Row] = []
    for mode, use_ray, workers in MODES:
        out = work / f"replay-{mode}-{workers}"
        calls = [(str(b), str(out), SWAP, [], True) for b in bags]
        out.mkdir()
        wall, _ = _timed(batchjobs.replay_job, calls, use_ray=use_ray, workers=workers)
        rows.append(
            {
                "work": "replay",
                "mode": mode,
                "workers": workers,
                "items": count,
                "wall_s": wall,
                "per_min": 60 * count / wall,
            }
        )
        shutil.rmtree(out)
    return rows


def _autolabel_rows(work: Path, quick: bool) -> list[Row]:
    seeds, grasps = ([1], 1) if quick else ([1, 2, 3, 4], 5)
    graph = str(ROOT / "graphs" / "autolabel.yaml")
    rows: list[Row] = []
    for mode, use_ray, workers in MODES:
        parts = work / f"label-{mode}-{workers}"
        calls = [(graph, s, grasps, str(parts / f"seed_{s}")) for s in seeds]
        wall, done = _timed(batchjobs.autolabel_job, calls, use_ray=use_ray, workers=workers)
        total = sum(r["grasps"] for r in done)
        rows.append(
            {
                "work": "autolabel",
                "mode": mode,
                "workers": workers,
                "items": total,
                "wall_s": wall,
                "per_min": 60 * total / wall,
            }
        )
    return rows


def _train_rows(work: Path, quick: bool) -> list[Row]:
    from perception.classify.synthetic import write_toy_dataset

    data = write_toy_dataset(work / "toy", grasps_per_class=16, frames_per_grasp=4, seed=0)
    size = (
        ["--input-px", "32", "--width", "0.125"]
        if quick
        else ["--input-px", "112", "--width", "0.5"]
    )
    epochs = "2" if quick else "4"
    rows: list[Row] = []
    for processes in (1, 2):
        # The epoch log is the checkpoint's (OUT.log.jsonl): torchrun would take a
        # `--log` option for its own `--log-dir` (argparse abbreviations).
        log = work / f"m{processes}.pt.log.jsonl"
        train = ["-m", "perception.classify", "train", str(data), "--epochs", epochs, *size]
        train += ["--out", str(work / f"m{processes}.pt"), "--threads", "1"]
        if processes == 1:
            command = [sys.executable, *train]
        else:
            torchrun = [sys.executable, "-m", "torch.distributed.run"]
            command = [*torchrun, "--standalone", "--nproc-per-node", str(processes), *train]
        subprocess.run(command, cwd=ROOT, check=True, capture_output=True, stdin=subprocess.DEVNULL)
        epochs_log = [json.loads(line) for line in log.read_text().splitlines()]
        rate = median(
            [e["samples_per_sec"] for e in epochs_log[1:]] or [epochs_log[0]["samples_per_sec"]]
        )
        rows.append(
            {
                "work": "train",
                "mode": "torchrun" if processes > 1 else "alone",
                "workers": processes,
                "items": int(epochs_log[-1].get("epoch", 0)),
                "per_sec": rate,
            }
        )
    base = rows[0]["per_sec"]
    for row in rows:
        row["vs_alone"] = row["per_sec"] / base
    return rows


def run(quick: bool) -> list[Row]:
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        work = Path(tmp)
        start = time.monotonic()
        run_tasks(batchjobs.summarize, [], [], address=None, workers=1, use_ray=True)
        rows: list[Row] = [
            {"work": "ray start", "mode": "ray", "workers": 1, "wall_s": time.monotonic() - start}
        ]
        for part in (_replay_rows, _autolabel_rows):
            measured = part(work, quick)
            loop = measured[0]["per_min"]
            for row in measured:
                row["vs_loop"] = row["per_min"] / loop
            rows += measured
        rows += _train_rows(work, quick)
    return rows


if __name__ == "__main__":
    main(
        "batch",
        run,
        columns=[
            "work",
            "mode",
            "workers",
            "items",
            "wall_s",
            "per_min",
            "vs_loop",
            "per_sec",
            "vs_alone",
        ],
    )
