"""The paper's three tasks over randomized scenes: ``python -m bench.tasks``.

Each run is a real graph (``launch.py``, every node its own process) recording a few
small topics to a bag, from which the figures are read; each scene is drawn from the
run's seed (the seeds are in the table):

* ``dish_loading``: ``graphs/dish_loading.yaml`` with ``supervisor.seed`` = seed (six
  objects, all four classes, random poses after a drop). Success: no object in a wrong
  bin. Objects per minute (of simulated time), classification accuracy (predicted =
  true class), routing accuracy (objects in their right bin; the manual bin is not).
* ``antagonism``: ``graphs/antagonism.yaml`` on a scene with random tilts (15-30 and
  10-20 degrees), a random slide and a random tap, with the pose node at LM and at IPOPT
  side by side. Success: the supervisor's verdict (p95 within 5 degrees and 3 mm, the
  tap re-acquired). Axis angle and off-axis distance (median, p95), time to re-acquire,
  and the latency from a camera frame to its pose estimate (median, p99).
* ``handover``: ``graph.yaml`` on a scene whose pull starts at a random time after the
  grasp is stable (2.0-2.8 s; the grasp turns stable at about 1.7 s), and the same
  scene held still. Success: released after the pull started, within 1 s. The graph's
  supervisor releases by the paper's shear rule; ``handover_force`` runs the same scenes
  releasing on the pull the bubbles' force shows (``supervisor.release_on=force``,
  ``docs/force.md``), side by side. Release latency two ways, from the pull's start (or
  the stable grasp, were it later): in data time to the frame that decided
  (``release_latency_ms``: the rule's frames), and through the graph
  (``release_graph_ms``: the recorder's receipt of the world's state at the pull's start
  to its receipt of the release, the pipeline's lag and the supervisor's wait included);
  false-release rate (releases during the still hold), camera frame to shear estimate
  latency.
* ``stacking``: ``graphs/stacking.yaml`` lowering a mug or a square bottle onto a
  support 5-30 mm under it. Success: placed (not dropped). Release latency (touch to
  release), how far the arm went past contact, the gap and tilt, shear latency.

Latencies run from the recorder's receipt of a frame's world state (what the cameras
render) to its receipt of the estimate made from that frame (same stamp): the whole
pipeline on one clock. The world runs in real time; on a loaded machine everything
trails (the figures say by how much); ``--rate-scale 0.5`` runs every world at half
real time (a loaded machine then keeps up; latencies stay wall-clock).

Scenes per task: ``RUNS`` by default (seeds 0 .. N-1), as many as fit in about four
minutes of graphs (each graph costs its scene plus several seconds to start and stop):
2 dish loading sinks (12 objects), 2 tracking scenes (4 graphs: LM and IPOPT), 3
handovers (6 graphs: pull and still hold) and 4 stackings. ``--runs N`` sets every
task's; ``--quick`` runs one stacking scene; ``--tasks a,b`` picks tasks.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import yaml

from bench.common import Row, main, median, percentile, progress
from messages.tasks import ObjectOutcome

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("dish_loading", "antagonism", "handover", "handover_force", "stacking")
RUNS = {"dish_loading": 2, "antagonism": 2, "handover": 3, "handover_force": 3, "stacking": 4}
TOPICS = (
    "^(supervisor/event|world/state|world/ground_truth|world/placement|pose/pose|shear/shear"
    "|classifier/probabilities)$"
)
RUN_TIMEOUT_SECS = 600
RATE_SCALE = [1.0]  # world.rate_scale of every run (--rate-scale)


def launch(graph: str, bag: Path, *args: str) -> tuple[int, str, dict[str, list], float]:
    """Run a graph recording ``TOPICS``; returns (exit code, output, topics, wall secs).

    Each topic maps to ``[(stamp_nanos, log_nanos, message), ...]`` in receive order.
    """
    from runtime.bag import BagReader

    start = time.monotonic()
    proc = subprocess.run(
        [
            *(sys.executable, "launch.py", graph, *args),
            *("--set", f"world.rate_scale={RATE_SCALE[0]}"),
            *("--record", str(bag), "--record-topics", TOPICS),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_SECS,
    )
    wall = time.monotonic() - start
    topics: dict[str, list] = {}
    if bag.exists():
        for m in BagReader(bag).messages():
            topics.setdefault(m.topic, []).append(
                (m.publish_time_nanos, m.log_time_nanos, m.decode())
            )
    return proc.returncode, proc.stdout + proc.stderr, topics, wall


def events(topics: dict[str, list], name: str) -> list[tuple[int, Any]]:
    return [(s, e) for s, _, e in topics.get("supervisor/event", []) if e.event == name]


def summary(topics: dict[str, list]) -> dict[str, Any]:
    found = events(topics, "summary")
    # The summary's record as plain values (its ``kind`` names which record it is).
    return msgspec.to_builtins(found[-1][1].data) if found and found[-1][1].data else {}


def latencies_ms(topics: dict[str, list], topic: str) -> list[float]:
    """From each frame to each message on ``topic`` made from it (milliseconds).

    The frame's time is when the recorder received the world's state of that instant
    (the state the cameras render; same stamp), the message's when it received the
    message: the whole pipeline, on one clock, at any ``rate_scale``.
    """
    frames = {stamp: log for stamp, log, _ in topics.get("world/state", [])}
    return [
        (log - frames[stamp]) / 1e6 for stamp, log, _ in topics.get(topic, []) if stamp in frames
    ]


def write_scene(template: str, out: Path, **changes: Any) -> str:
    data = yaml.safe_load((ROOT / template).read_text())
    data.update(changes)
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(out)


# -- the tasks --------------------------------------------------------------------------


def dish_loading(seed: int, tmp: Path) -> list[dict[str, Any]]:
    code, _, topics, wall = launch(
        "graphs/dish_loading.yaml", tmp / "dish.mcap", "--set", f"supervisor.seed={seed}"
    )
    objects = [e.data for _, e in events(topics, "object") if isinstance(e.data, ObjectOutcome)]
    s = summary(topics)
    return [
        {
            "success": code == 0 and bool(s) and s["wrong"] == 0,
            "objects": len(objects),
            "objects_per_minute": s.get("objects_per_minute", float("nan")),
            "classified_right": sum(o.predicted == o.true_class for o in objects),
            "routed_right": sum(bool(o.right) for o in objects),
            "manual": s.get("manual", 0),
            "regrasps": s.get("regrasps", 0),
            "classify_latency_ms": latencies_ms(topics, "classifier/probabilities"),
            "wall_secs": wall,
        }
    ]


def antagonism(seed: int, tmp: Path) -> list[dict[str, Any]]:
    rng = np.random.default_rng([seed, 2])
    roll, yaw = rng.uniform(15, 30), rng.uniform(10, 20)
    slide, tap_mm, tap_deg = rng.uniform(0.002, 0.005), rng.uniform(2, 4), rng.uniform(5, 10)
    z0 = 0.005
    frames = [
        {"t_secs": 0.0, "xyz_m": [0.0, 0.0, z0]},
        {"t_secs": 2.0, "xyz_m": [0.0, 0.0, z0]},
        {"t_secs": 2.8, "xyz_m": [0.0, 0.0, z0], "rpy_deg": [float(roll), 0, 0]},
        {"t_secs": 3.6, "xyz_m": [0.0, 0.0, z0]},
        {"t_secs": 4.2, "xyz_m": [0.0, 0.0, z0], "rpy_deg": [0, 0, float(yaw)]},
        {"t_secs": 4.8, "xyz_m": [0.0, 0.0, z0], "rpy_deg": [0, 30, 0]},
        {"t_secs": 5.4, "xyz_m": [0.0, 0.0, z0 + float(slide)]},
        {"t_secs": 6.0, "xyz_m": [0.0, 0.0, z0 + float(slide)]},
        {
            "t_secs": 6.033,
            "xyz_m": [0.0, float(tap_mm) / 1000, z0 + float(slide)],
            "rpy_deg": [float(tap_deg), 0, 0],
        },
    ]
    scene = write_scene(
        "scenes/mug_antagonism.yaml", tmp / "antagonism.yaml", seed=100 + seed, trajectory=frames
    )
    out = []
    for solver in ("lm", "ipopt"):
        code, _, topics, wall = launch(
            "graphs/antagonism.yaml",
            tmp / f"antagonism_{solver}.mcap",
            "--set",
            f"world.scene={scene}",
            "--swap",
            f"pose=pose_estimator.{solver}",
        )
        s = summary(topics)
        jolts = s.get("jolts", [])
        tracked = bool(s.get("estimates"))  # errors of no estimate are no errors
        out.append(
            {
                "solver": solver,
                "success": code == 0 and bool(s.get("success")),
                "estimates": s.get("estimates", 0),
                "axis_deg": [s["axis_deg"]["median"], s["axis_deg"]["p95"]] if tracked else [],
                "offaxis_mm": [s["offaxis_mm"]["median"], s["offaxis_mm"]["p95"]]
                if tracked
                else [],
                "reacquire_secs": [
                    j["reacquire_secs"] for j in jolts if j["reacquire_secs"] is not None
                ],
                "pose_latency_ms": latencies_ms(topics, "pose/pose"),
                "wall_secs": wall,
            }
        )
    return out


def pull_start_nanos(topics: dict[str, list]) -> int | None:
    truth = topics.get("world/ground_truth", [])
    if not truth:
        return None
    first = truth[0][2].tool_from_object
    moved = [s for s, _, t in truth if not np.allclose(t.tool_from_object, first, atol=1e-9)]
    return moved[0] if moved else None


def pull_start_secs(seed: int) -> float:
    """When the handover's pull of ``seed`` starts (scene time): after the stable grasp
    (about 1.7 s), so that the whole delay from the pull is the release's."""
    return float(np.random.default_rng([seed, 3]).uniform(2.0, 2.8))


def release_latency(topics: dict[str, list]) -> tuple[float | None, list[float]]:
    """From the pull's start (or the stable grasp, were it later: no release can be
    decided before it) to the first release: seconds of data time (None: no release or
    no pull), and milliseconds through the graph (the recorder's receipts of that
    instant's world state and of the release; empty when it has no such state)."""
    pull = pull_start_nanos(topics)
    stable = [s for s, _ in events(topics, "stable")]
    if pull is not None and stable:
        pull = max(pull, stable[0])
    releases = [
        (s, log) for s, log, e in topics.get("supervisor/event", []) if e.event == "release"
    ]
    if not releases or pull is None:
        return None, []
    frames = {stamp: log for stamp, log, _ in topics.get("world/state", [])}
    graph_ms = [(releases[0][1] - frames[pull]) / 1e6] if pull in frames else []
    return (releases[0][0] - pull) / 1e9, graph_ms


def handover(seed: int, tmp: Path, *extra: str) -> list[dict[str, Any]]:
    start = pull_start_secs(seed)
    z0 = 0.005
    pulled = write_scene(
        "scenes/handover_task.yaml",
        tmp / "pull.yaml",
        seed=200 + seed,
        trajectory=[
            {"t_secs": 0.0, "xyz_m": [0.0, 0.0, z0]},
            {"t_secs": start, "xyz_m": [0.0, 0.0, z0]},
            {"t_secs": start + 1.0, "xyz_m": [0.0, 0.0, z0 + 0.015]},
            {"t_secs": 4.0, "xyz_m": [0.0, 0.0, z0 + 0.040]},
        ],
    )
    held = write_scene("scenes/mug_hold.yaml", tmp / "hold.yaml", seed=200 + seed)
    _, _, topics, wall = launch(
        "graph.yaml", tmp / "pull.mcap", "--set", f"world.scene={pulled}", *extra
    )
    latency, graph_ms = release_latency(topics)
    _, _, held_topics, held_wall = launch(
        "graph.yaml", tmp / "hold.mcap", "--set", f"world.scene={held}", *extra
    )
    return [
        {
            "success": latency is not None and 0 < latency <= 1.0,
            "release_latency_ms": [] if latency is None else [latency * 1000],
            "release_graph_ms": graph_ms,
            "false_release": bool(events(held_topics, "release")),
            "shear_latency_ms": latencies_ms(topics, "shear/shear")
            + latencies_ms(held_topics, "shear/shear"),
            "wall_secs": wall + held_wall,
        }
    ]


def stacking(seed: int, tmp: Path) -> list[dict[str, Any]]:
    rng = np.random.default_rng([seed, 4])
    template = ("scenes/stack_on_table.yaml", "scenes/stack_on_mug.yaml")[seed % 2]
    base = yaml.safe_load((ROOT / template).read_text())
    support = dict(base["support"], clearance_m=float(rng.uniform(0.005, 0.03)))
    scene = write_scene(template, tmp / "stack.yaml", seed=300 + seed, support=support)
    code, _, topics, wall = launch(
        "graphs/stacking.yaml", tmp / "stack.mcap", "--set", f"world.scene={scene}"
    )
    placement = topics.get("world/placement", [])
    truth = placement[0][2] if placement else None
    touched = truth is not None and truth.touch_secs is not None
    return [
        {
            "success": code == 0 and truth is not None and truth.placed,
            "release_latency_ms": [(truth.t_secs - truth.touch_secs) * 1000]
            if truth is not None and truth.touch_secs is not None
            else [],
            "push_mm": [truth.push_m * 1000] if truth else [],
            "gap_mm": [truth.gap_m * 1000] if truth else [],
            "tilt_deg": [truth.tilt_deg] if truth else [],
            "false_release": bool(placement) and not touched,
            "shear_latency_ms": latencies_ms(topics, "shear/shear"),
            "wall_secs": wall,
        }
    ]


RUNNERS = {
    "dish_loading": dish_loading,
    "antagonism": antagonism,
    "handover": handover,
    "handover_force": lambda seed, tmp: handover(seed, tmp, "--set", "supervisor.release_on=force"),
    "stacking": stacking,
}


# -- the table ----------------------------------------------------------------------------


def _flat(runs: list[dict[str, Any]], key: str, index: int | None = None) -> list[float]:
    out: list[float] = []
    for r in runs:
        values = r.get(key, [])
        if index is not None:
            values = values[index : index + 1]
        out += [float(v) for v in values]
    return out


def aggregate(task: str, seeds: list[int], runs: list[dict[str, Any]]) -> Row:
    """One row of the table from the runs of one task (and solver)."""
    row: Row = {
        "task": task,
        "solver": runs[0].get("solver", ""),
        "runs": len(runs),
        "seeds": ",".join(str(s) for s in seeds),
        "success_rate": float(np.mean([r["success"] for r in runs])),
        "wall_secs_median": median([r["wall_secs"] for r in runs]),
        "rate_scale": RATE_SCALE[0],
    }
    if task == "dish_loading":
        objects = sum(r["objects"] for r in runs) or 1
        row["objects_per_minute"] = median([r["objects_per_minute"] for r in runs])
        row["classification_accuracy"] = sum(r["classified_right"] for r in runs) / objects
        row["routing_accuracy"] = sum(r["routed_right"] for r in runs) / objects
        row["manual_rate"] = sum(r["manual"] for r in runs) / objects
        lat = _flat(runs, "classify_latency_ms")
        row["classify_latency_ms_median"] = median(lat)
        row["classify_latency_ms_p99"] = percentile(lat, 99)
    elif task == "antagonism":
        row["estimates_median"] = median([r["estimates"] for r in runs])
        row["axis_deg_median"] = median(_flat(runs, "axis_deg", 0))
        row["axis_deg_p95"] = median(_flat(runs, "axis_deg", 1))
        row["offaxis_mm_median"] = median(_flat(runs, "offaxis_mm", 0))
        row["offaxis_mm_p95"] = median(_flat(runs, "offaxis_mm", 1))
        row["reacquire_secs_median"] = median(_flat(runs, "reacquire_secs"))
        lat = _flat(runs, "pose_latency_ms")
        row["pose_latency_ms_median"] = median(lat)
        row["pose_latency_ms_p99"] = percentile(lat, 99)
    else:
        lat = _flat(runs, "release_latency_ms")
        row["release_latency_ms_median"] = median(lat)
        row["false_release_rate"] = float(np.mean([r["false_release"] for r in runs]))
        if task.startswith("handover"):
            row["release_graph_ms_median"] = median(_flat(runs, "release_graph_ms"))
        if task == "stacking":
            row["push_mm_median"] = median(_flat(runs, "push_mm"))
            row["gap_mm_median"] = median(_flat(runs, "gap_mm"))
        shear = _flat(runs, "shear_latency_ms")
        row["shear_latency_ms_median"] = median(shear)
        row["shear_latency_ms_p99"] = percentile(shear, 99)
    return row


def sweep(tasks: tuple[str, ...], n_runs: int | None) -> list[Row]:
    """Every (task, seed) in turn; ``n_runs`` scenes per task, or ``RUNS``."""
    points = [(t, seed) for t in tasks for seed in range(n_runs or RUNS[t])]
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {t: {} for t in tasks}
    for task, seed in progress(points, "tasks", label=lambda p: f"{p[0]} seed {p[1]}"):
        with tempfile.TemporaryDirectory(prefix=f"bench-{task}-") as tmp:
            for run in RUNNERS[task](seed, Path(tmp)):
                runs[task].setdefault(run.get("solver", ""), []).append(run)
    return [
        aggregate(task, list(range(n_runs or RUNS[task])), solver_runs)
        for task in tasks
        for solver_runs in runs[task].values()
    ]


def run(quick: bool, tasks: tuple[str, ...] = TASKS, n_runs: int | None = None) -> list[Row]:
    """The sweep: one stacking scene with ``quick``, else ``n_runs`` (or ``RUNS``) per task."""
    return sweep(("stacking",), 1) if quick else sweep(tasks, n_runs)


COLUMNS = [
    "task",
    "solver",
    "runs",
    "seeds",
    "success_rate",
    "objects_per_minute",
    "classification_accuracy",
    "routing_accuracy",
    "estimates_median",
    "axis_deg_median",
    "axis_deg_p95",
    "offaxis_mm_median",
    "offaxis_mm_p95",
    "reacquire_secs_median",
    "release_latency_ms_median",
    "release_graph_ms_median",
    "false_release_rate",
    "push_mm_median",
    "pose_latency_ms_median",
    "pose_latency_ms_p99",
    "shear_latency_ms_median",
    "shear_latency_ms_p99",
]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--runs", type=int, default=None, help="scenes per task (seeds 0..N-1)")
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks")
    parser.add_argument("--rate-scale", type=float, default=1.0, help="world.rate_scale")
    extra, rest = parser.parse_known_args()
    RATE_SCALE[0] = extra.rate_scale
    chosen = tuple(t for t in extra.tasks.split(",") if t)
    unknown = sorted(set(chosen) - set(TASKS))
    if unknown or (extra.runs is not None and extra.runs < 1) or not extra.rate_scale > 0:
        sys.exit(f"bench.tasks: --tasks must name {TASKS} and --runs be >= 1, got {extra}")
    main(
        "tasks",
        lambda quick: run(quick, chosen, extra.runs),
        columns=COLUMNS,
        argv=rest,
    )
