"""Pose estimation: accuracy against time for each solver, point count, tolerance, start;
and the basin of convergence (success against initial tilt).

One run builds one set of cases and every row uses the same ones:

- ``synthetic``: the mug's body (the paper's cylinder, r 40 mm, h 95 mm) at random side
  grasps, two-bubble clouds sampled from the surface with 1 mm noise along the camera
  rays (``perception.pose.synthetic``);
- ``sim``: the same poses rendered by the simulator (``sim.render_grasp``: membrane,
  depth and ToF noise), turned into grasp clouds by the real contact filter against a
  free-bubble reference (``perception.contact``). Skipped, and said so, if ``sim`` is
  missing.

Each cloud is subsampled to the kept point count (1k, 3k, 10k, 20k). ``warm`` starts
from the truth tilted 3 degrees and moved 2 mm, given as a seed (an unverified prior: the
estimator searches its turns too; the tracking path is ``bench.pose_hard``'s ``track``
rows); ``cold`` has no prior (data
and cardinal seeds, turns checked). Success: axis error under 2 degrees and off-axis
error under 2 mm. The axis error ignores the flip of the axis (a plain cylinder's two
ends look alike). Basin rows: seeds tilted by ``tilt_deg`` about a random direction
perpendicular to the axis (and moved 5 mm), solved once (``success_rate_local``) and
through the estimator's wrong-minimum recovery (``success_rate``), 3k points.

Every estimator row carries ``silent_wrong``: its answers outside the success bounds
whose status was ``ok`` or ``recovered`` (the goal is 0), and an ``object`` naming the
shape; accuracy rows also the right answers called ``suspect`` (``right_suspect_share``)
and the coverage of the stated 95% region (``coverage95``, ``coverage95_ok``), as
``bench.pose_hard`` defines them; ``default`` marks the default graph's settings (IPOPT,
tight tolerance). ``warm_cost`` rows: a seed 3 degrees off given to the estimator,
beside one local solve from it, the judgement alone at that solve's answer and a cold
start (CPU time and its ratio to one solve).
The rows of ``bench.pose_hard`` follow (other shapes and sizes, box edges and corners,
noise 0.5-3 mm, bad seeds, tracking and cold-start time by solver, size mismatch with
and without ``fit_dims``, degenerate clouds); see its docstring.

Timing: wall time of the whole estimate (all seeds), one process pinned to one thread,
and its process CPU time (``cpu_ms_median``), which a machine shared with other jobs
disturbs far less than wall time. The IPOPT solvers are built (and jit-compiled) for
each point count before timing.

    python -m bench.pose [--quick] [--json]
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench import pose_hard
from bench.common import Row, main, median, one_core, percentile, plain_log_ticks, progress
from geometry import objects, se3
from geometry.camera import PinholeCamera
from geometry.fields import Field
from perception.contact import ContactParams, ContactPatcher
from perception.pose import cloud, judge, metrics, problem, synthetic
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.icp import IcpParams, IcpSolver
from perception.pose.ipopt import IpoptParams, IpoptSolver, jit_available
from perception.pose.lm import LMParams, LMSolver

NOISE_M = 0.001
AXIS_OK_DEG = 2.0
OFFAXIS_OK_M = 0.002
DEPTH_M = 0.005  # indentation of the synthetic and simulated grasps

Case = dict[str, Any]


def _model() -> tuple[objects.ObjectModel, Field]:
    mug = objects.make("mug")
    return mug, mug.field.children[0]  # the body: the paper fits a cylinder


def _cloud_from_sim(truth: np.ndarray, width_m: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    import sim

    effects = ("membrane", "depth", "tof_noise")
    far = truth.copy()
    far[:3, 3] += [0.0, 0.0, 1.0]  # the object out of reach: free bubbles
    free = sim.render_grasp("mug", far, 0.11, effects=effects, seed=seed)
    held = sim.render_grasp("mug", truth, width_m, effects=effects, seed=seed, frame_index=1)
    patcher = ContactPatcher(ContactParams(threshold_m=0.003, max_points=10**6))
    frames = {}
    for side, msg in held.images.items():
        patcher.update_reference(side, free.images[side].depth_m)
        h, w = msg.depth_m.shape
        cam = PinholeCamera(
            width_px=w,
            height_px=h,
            fx_px=msg.fx_px,
            fy_px=msg.fy_px,
            cx_px=msg.cx_px,
            cy_px=msg.cy_px,
        )
        frames[side] = (msg.depth_m, cam, msg.tool_from_sensor)
    cloud = patcher.extract(frames)
    return cloud.points_in_tool.astype(np.float64), cloud.bubble


def make_cases(n_cases: int, max_points: int, with_sim: bool) -> tuple[list[Case], str]:
    """Poses, and a synthetic (and simulated) cloud for each."""
    mug, body = _model()
    body_model = objects.ObjectModel(
        name="mug_body", class_label="mug", field=body, symmetric_about_z=True
    )
    rng = np.random.default_rng(2026)
    cases: list[Case] = []
    sim_note = "sim: used"
    if with_sim:
        try:
            import sim  # noqa: F401
        except ImportError as err:
            with_sim = False
            sim_note = f"sim: unavailable ({err})"
    else:
        sim_note = "sim: off"
    radius = mug.dims_m["radius_m"]
    gripper_cap = 0.025 - 0.02  # cap height minus plate outset (geometry.gripper defaults)
    for k in range(n_cases):
        truth = synthetic.random_grasp_pose(mug, rng)
        pts, bubble = synthetic.grasp_cloud(
            body_model, truth, n_points=max_points, noise_m=NOISE_M, rng=rng, depth_m=DEPTH_M
        )
        cases.append(
            {"source": "synthetic", "truth": truth, "points": pts, "bubble": bubble, "k": k}
        )
        if with_sim:
            width = 2.0 * radius + 2.0 * gripper_cap - 2.0 * DEPTH_M
            spts, sbub = _cloud_from_sim(truth, width, seed=k)
            if len(spts) >= 100:
                cases.append(
                    {"source": "sim", "truth": truth, "points": spts, "bubble": sbub, "k": k}
                )
    return cases, sim_note


def _subsample(case: Case, n: int) -> tuple[np.ndarray, np.ndarray]:
    pts, bub = case["points"], case["bubble"]
    if len(pts) > n:
        idx = np.sort(np.random.default_rng(case["k"]).choice(len(pts), n, replace=False))
        pts, bub = pts[idx], bub[idx]
    return pts, bub


def _solvers(body: Field, tol: str, use_jit: bool) -> dict[str, Callable[[], Any]]:
    loose = tol == "loose"
    return {
        "lm": lambda: LMSolver(body, LMParams(cost_tol=1e-4 if loose else 1e-8)),
        "ipopt": lambda: IpoptSolver(
            body, IpoptParams(tol=1e-4 if loose else 1e-8, jit="on" if use_jit else "off")
        ),
        "ipopt_exact": lambda: IpoptSolver(
            body,
            IpoptParams(
                tol=1e-4 if loose else 1e-8, jit="on" if use_jit else "off", hessian="exact"
            ),
        ),
        "icp": lambda: IcpSolver(body, IcpParams(rms_tol_m=1e-5 if loose else 1e-7)),
    }


def _score(result: problem.FitResult, truth: np.ndarray) -> tuple[float, float]:
    return (
        metrics.axis_error_deg(result.tool_from_object, truth, flip_symmetric=True),
        metrics.offaxis_error_m(result.tool_from_object, truth),
    )


def _silent_wrong(right: list[bool], claimed: list[bool]) -> int:
    """Answers outside the success bounds whose status was ``ok`` or ``recovered``."""
    return sum(1 for r, c in zip(right, claimed, strict=True) if c and not r)


def _warm_seed(truth: np.ndarray, k: int) -> np.ndarray:
    return synthetic.tilted_seed(truth, 3.0, np.random.default_rng(1000 + k), offset_m=0.002)


def accuracy_rows(
    cases: list[Case],
    points: list[int],
    tols: dict[int, list[str]],
    solvers: list[str],
    use_jit: bool,
    starts: tuple[str, ...] = ("warm", "cold"),
) -> list[Row]:
    _, body = _model()
    rows: list[Row] = []
    for n in progress(points, "bench.pose", label=lambda n: f"accuracy, {n} points, {solvers}"):
        for tol in tols.get(n, ["tight"]):
            makers = _solvers(body, tol, use_jit)
            for name in solvers:
                solver = makers[name]()
                if isinstance(solver, IpoptSolver):
                    solver.prepare(n)
                    # One untimed solve: the first call of a jit-compiled solver loads it.
                    warm_pts, _ = _subsample(cases[0], n)
                    solver.solve(warm_pts, se3.invert(cases[0]["truth"]))
                for start in starts:
                    for source in sorted({c["source"] for c in cases}):
                        errs, offs, secs, judged = [], [], [], []
                        est = PoseEstimator(solver, EstimatorParams(track=False, max_points=n))
                        for case in (c for c in cases if c["source"] == source):
                            pts, bub = _subsample(case, n)
                            seed = _warm_seed(case["truth"], case["k"]) if start == "warm" else None
                            t0, c0 = time.perf_counter(), time.process_time()
                            result = est.estimate(pts, bub, seed_tool_from_object=seed)
                            secs.append(time.perf_counter() - t0)
                            cpu = time.process_time() - c0
                            a, o = _score(result, case["truth"])
                            errs.append(a)
                            offs.append(o)
                            judged.append(pose_hard.judged(body, result, case["truth"], cpu))
                        row = pose_hard.summary(
                            judged,
                            {
                                "kind": "accuracy",
                                "object": "mug_body",
                                "source": source,
                                "solver": name,
                                "points": n,
                                "tol": tol,
                                "start": start,
                            },
                        )
                        row["default"] = "*" if name == "ipopt" and tol == "tight" else ""
                        rows.append(
                            {
                                **row,
                                "axis_err_deg_median": median(errs),
                                "axis_err_deg_p95": percentile(errs, 95),
                                "offaxis_err_mm_median": 1e3 * median(offs),
                                "offaxis_err_mm_p95": 1e3 * percentile(offs, 95),
                                "solve_ms_median": 1e3 * median(secs),
                                "rate_hz_median": 1.0 / max(median(secs), 1e-9),
                                "cpu_rate_hz_median": 1.0 / max(row["cpu_ms_median"] / 1e3, 1e-9),
                                "seeds_mean": float(np.mean([r.seeds_tried for r, *_ in judged])),
                            }
                        )
    return rows


def _tight_estimator(name: str, n: int, use_jit: bool) -> tuple[Any, PoseEstimator]:
    """A tight-tolerance solver (IPOPT prepared for ``n`` and the screening size) and an
    estimator around it that keeps no track."""
    _, body = _model()
    solver = _solvers(body, "tight", use_jit)[name]()
    if isinstance(solver, IpoptSolver):
        solver.prepare(n)
        solver.prepare(EstimatorParams().screen_points)
    return solver, PoseEstimator(solver, EstimatorParams(track=False, max_points=n))


def warm_cost_rows(cases: list[Case], n: int, solvers: list[str], use_jit: bool) -> list[Row]:
    """What a seed 3 degrees and 2 mm off costs the estimator (``warm_seed``), beside one
    local solve from the same seed (``one_solve``), the judgement alone at that solve's
    answer (``judgement``: the noise measured from the cloud, the camera rays and the
    uncertainty, which every estimate pays) and a cold start (``cold``): process CPU
    time on one thread, and its ratio to one solve."""
    synth = [c for c in cases if c["source"] == "synthetic"]
    rows: list[Row] = []
    for name in progress(solvers, "bench.pose", label=lambda s: f"warm seed cost, {s}, {n} points"):
        solver, est = _tight_estimator(name, n, use_jit)
        cpu: dict[str, list[float]] = {
            "one_solve": [],
            "judgement": [],
            "warm_seed": [],
            "cold": [],
        }
        seeds: dict[str, list[int]] = {k: [] for k in cpu}
        for case in synth:
            pts, bub = _subsample(case, n)
            seed = _warm_seed(case["truth"], case["k"])
            est.estimate(pts, bub)  # untimed: first calls (libraries, caches) paid here
            for start in cpu:
                c0 = time.process_time()
                if start == "one_solve":
                    answer = solver.solve(pts, se3.invert(seed))
                    tried = 1
                elif start == "judgement":
                    rays = cloud.camera_rays(pts, bub)
                    cloud.estimate_noise_m(pts, rays)
                    judge.uncertainty(
                        solver.field.resized(**answer.dims_m),
                        answer.object_from_tool,
                        pts,
                        rays_in_tool=rays,
                    )
                    tried = 0
                else:
                    prior = seed if start == "warm_seed" else None
                    tried = est.estimate(pts, bub, seed_tool_from_object=prior).seeds_tried
                cpu[start].append(time.process_time() - c0)
                seeds[start].append(tried)
        one = median(cpu["one_solve"])
        for start, values in cpu.items():
            rows.append(
                {
                    "kind": "warm_cost",
                    "object": "mug_body",
                    "source": "synthetic",
                    "solver": name,
                    "points": n,
                    "start": start,
                    "default": "*" if name == "ipopt" else "",
                    "cases": len(values),
                    "cpu_ms_median": 1e3 * median(values),
                    "cost_vs_one_solve": median(values) / max(one, 1e-12),
                    "seeds_mean": float(np.mean(seeds[start])),
                }
            )
    return rows


def basin_rows(
    cases: list[Case], tilts: list[float], n: int, solvers: list[str], use_jit: bool
) -> list[Row]:
    synth = [c for c in cases if c["source"] == "synthetic"]
    rows: list[Row] = []
    for name in progress(solvers, "bench.pose", label=lambda s: f"basin, {s}, {n} points"):
        solver, est = _tight_estimator(name, n, use_jit)
        for tilt in tilts:
            local_ok, robust_ok, claimed = [], [], []
            for case in synth:
                pts, bub = _subsample(case, n)
                rng = np.random.default_rng(int(tilt * 1000) + case["k"])
                seed = synthetic.tilted_seed(case["truth"], tilt, rng, offset_m=0.005)
                a, o = _score(solver.solve(pts, se3.invert(seed)), case["truth"])
                local_ok.append(a < AXIS_OK_DEG and o < OFFAXIS_OK_M)
                result = est.estimate(pts, bub, seed_tool_from_object=seed)
                a, o = _score(result, case["truth"])
                robust_ok.append(a < AXIS_OK_DEG and o < OFFAXIS_OK_M)
                claimed.append(result.status in ("ok", "recovered"))
            rows.append(
                {
                    "kind": "basin",
                    "object": "mug_body",
                    "source": "synthetic",
                    "solver": name,
                    "points": n,
                    "tilt_deg": tilt,
                    "cases": len(synth),
                    "success_rate": float(np.mean(robust_ok)),
                    "success_rate_local": float(np.mean(local_ok)),
                    "silent_wrong": _silent_wrong(robust_ok, claimed),
                }
            )
    return rows


def run(quick: bool) -> list[Row]:
    one_core()
    use_jit = jit_available("gcc")
    if quick:
        cases, note = make_cases(3, 3000, with_sim=True)
        rows = accuracy_rows(cases, [1000], {}, ["lm", "ipopt", "icp"], use_jit=False)
        rows += basin_rows(cases, [0.0, 45.0, 90.0], 1000, ["lm"], use_jit=False)
        rows += warm_cost_rows(cases, 1000, ["lm"], use_jit=False)
    else:
        # Sized so that ``python -m bench.report`` (every sweep) ends in 20 minutes on two
        # cores: 8 poses x (synthetic + simulated) clouds per point of the sweep.
        cases, note = make_cases(8, 20000, with_sim=True)
        points = [1000, 3000, 10000, 20000]
        tols = {10000: ["tight", "loose"]}
        rows = accuracy_rows(cases, points, tols, ["lm", "ipopt"], use_jit)
        # ICP is slow (k-d tree queries, many iterations): cold only on small clouds.
        rows += accuracy_rows(cases, [1000, 3000], {}, ["icp"], use_jit)
        rows += accuracy_rows(cases, [10000], {}, ["icp"], use_jit, starts=("warm",))
        # The exact Hessian, for the cost the Gauss-Newton one saves.
        rows += accuracy_rows(cases, [10000], {}, ["ipopt_exact"], use_jit, starts=("warm",))
        rows += warm_cost_rows(cases, 10000, ["lm", "ipopt"], use_jit)
        rows += warm_cost_rows(cases, 3000, ["icp"], use_jit)
        tilts = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0]
        basin_cases = make_cases(25, 3000, with_sim=False)[0]
        rows += basin_rows(basin_cases, tilts, 3000, ["lm", "ipopt"], use_jit)
        rows += basin_rows(basin_cases[:12], tilts, 3000, ["icp"], use_jit)
    for row in rows:
        row["note"] = f"{note}; ipopt jit: {'on' if use_jit and not quick else 'off'}"
    # Shapes, sizes, noise, bad starts, size mismatch and degenerate clouds.
    return rows + pose_hard.run(quick)


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    colors = {"lm": "C0", "ipopt": "C1", "icp": "C2", "ipopt_exact": "C3"}
    sizes = {1000: 20, 3000: 40, 10000: 70, 20000: 110}  # marker area by point count
    for row in rows:
        if row["kind"] != "accuracy" or row["tol"] != "tight":
            continue
        color = colors[row["solver"]]
        ax1.scatter(
            row["cpu_ms_median"],
            max(row["axis_err_deg_median"], 1e-3),
            s=sizes.get(row["points"], 40),
            marker="o" if row["start"] == "warm" else "s",
            facecolors=color if row["source"] == "synthetic" else "none",
            edgecolors=color,
        )
    plain_log_ticks(ax1, "xy")
    ax1.set_xlabel("CPU time per estimate, median (ms, one core)")
    ax1.set_ylabel("axis error, median (deg)")
    ax1.set_title("accuracy against time (mug body, 1 mm noise)")
    handles = [
        Line2D([], [], marker="o", ls="", color=c, label=n)
        for n, c in colors.items()
        if any(r["kind"] == "accuracy" and r["solver"] == n for r in rows)
    ]
    handles += [
        Line2D([], [], marker="o", ls="", color="gray", label="seed 3 deg off (searched)"),
        Line2D([], [], marker="s", ls="", color="gray", label="cold start (no seed)"),
        Line2D([], [], marker="o", ls="", color="gray", mfc="none", label="simulated cloud"),
        Line2D([], [], marker="o", ls="", color="gray", label="synthetic cloud"),
        Line2D([], [], ls="", label="marker size: points 1k-20k"),
    ]
    ax1.legend(handles=handles, fontsize=7, loc="best")
    basin_points = sorted({r["points"] for r in rows if r["kind"] == "basin"})
    for name, color in colors.items():
        basin = [r for r in rows if r["kind"] == "basin" and r["solver"] == name]
        if basin:
            tilts = [r["tilt_deg"] for r in basin]
            ax2.plot(
                tilts,
                [r["success_rate"] for r in basin],
                "-o",
                color=color,
                label=f"{name}, estimator (turns and re-seeds)",
            )
            ax2.plot(
                tilts,
                [r["success_rate_local"] for r in basin],
                "--",
                color=color,
                label=f"{name}, one local solve",
            )
    ax2.set_xlabel("initial tilt of the seed (deg)")
    ax2.set_ylabel("success rate (axis < 2 deg, off-axis < 2 mm)")
    ax2.set_ylim(0, 1.05)
    ax2.legend(fontsize=7)
    ax2.set_title(f"basin of convergence ({', '.join(map(str, basin_points))} points)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


COLUMNS = [
    "kind",
    "object",
    "source",
    "solver",
    "points",
    "tol",
    "start",
    "tilt_deg",
    "axis_err_deg_median",
    "axis_err_deg_p95",
    "offaxis_err_mm_median",
    "offaxis_err_mm_p95",
    "default",
    "success_rate",
    "success_rate_local",
    "right_suspect_share",
    "silent_wrong",
    "coverage95",
    "coverage95_lo",
    "coverage95_hi",
    "coverage95_ok",
    "region95_deg_median",
    "fit_dims",
    "noise_mm",
    "suspect_rate",
    "solve_ms_median",
    "rate_hz_median",
    "cpu_ms_median",
    "cost_vs_one_solve",
    "seeds_mean",
]

if __name__ == "__main__":
    main("pose", run, columns=COLUMNS, plot=plot)
