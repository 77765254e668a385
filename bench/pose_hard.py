"""Pose estimation on hard input: shapes, sizes, noise, bad starts, degenerate clouds, and
size mismatch with and without ``fit_dims``; every row counts its silent wrong answers.

Objects (``object``): cylinders of radius 30, 40 (the mug's body) and 50 mm held by
their side; a 60x60x160 mm box squeezed on two faces (``box_face``), over two long
edges (``box_edge``: turned 45 degrees about its axis) and over two corners
(``box_corner``: its body diagonal across the closing axis); the whole PET bottle
(body, shoulder, neck) held by its body (``bottle``: the patch cannot tell its ends
apart, which the estimate reports in ``alternatives``). Synthetic two-bubble
clouds (``perception.pose.synthetic``) with noise along the camera rays.

Starts (``start``): ``cold`` (no prior), ``bad_seed`` (the truth turned 90 degrees about
a random object axis, or tilted 80 degrees for bodies of revolution, and moved 3 mm),
``track`` (the second estimate on the same cloud: the tracking path).

Success: within 2 degrees and 2 mm of the truth up to the object's symmetry, counting
only the directions observed: a slide or turn that neither the estimate nor the patch
at the true pose observes is no error (``metrics.right`` with the cloud).
The verdict (goals in brackets): ``right_ok_rate``, right and ``ok`` or ``recovered``;
``right_suspect_share``, right but ``suspect``, as a share of the right answers (under
5%); ``silent_wrong``, answers outside those bounds whose status was ``ok`` or
``recovered`` (0); ``coverage95``, the share of answers whose stated 95% region
(``PoseEstimate.covariance``) holds the truth (``metrics.covered``; 93-97%), and
``coverage95_ok`` the same over the answers ``ok`` or ``recovered`` (a wrong minimum
called ``suspect`` counts against the first, not the second);
``suspect_rate``, the share reported ``suspect``. ``default``: ``*`` on the rows with
the default graph's settings (``pose_estimator.ipopt``, default parameters).

``coverage95_lo`` and ``coverage95_hi``: its Wilson 95% interval over the row's cases.

Coverage (``kind: coverage``): the 95% region's coverage per shape and noise on 200
clouds each (clouds 200 on; the calibration was fitted on 100-111), LM seeded 5 degrees
and 2 mm off the truth, one solve and the judgement per cloud (``search: false``: the
region is the minimum's, whichever start reached it); a cell's Wilson interval is then
about +-3 points at 95%.

Size mismatch (``kind: size``): the true cylinder's radius is the model's plus 1-8 mm;
IPOPT without and with ``fit_dims: [radius]`` (bounds +-20%), seeded 10 degrees off.

Degenerate clouds (``kind: degenerate``): 3000 identical points, collinear points, a
noisy plane with a seed, an empty cloud; without a prior no answer can be right, so
every ``ok`` or ``recovered`` is silent wrong; the seeded plane may be right along what
it observes (the face the seed names: its position and tilt).

Timing: process CPU time of the whole estimate on one thread (``cpu_ms_median``).

    python -m bench.pose_hard [--quick] [--json]
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from bench.common import Row, main, median, one_core, percentile, progress
from bench.heldout import wilson_interval
from geometry import fields, objects, se3
from geometry.objects import ObjectModel
from perception.pose import metrics, problem, synthetic
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.ipopt import IpoptParams, IpoptSolver, jit_available
from perception.pose.lm import LMSolver

#: The first cloud of the coverage rows: ``judge.INFLATION`` was fitted on clouds 100-111,
#: the judgement's shares on 600-699 (``bench.pose_calib``).
COVERAGE_CLOUDS = 200
AXIS_OK_DEG = 2.0
OFFSET_OK_M = 0.002
GOOD = ("ok", "recovered")


def _cylinder(radius_m: float, height_m: float) -> ObjectModel:
    return ObjectModel(
        name=f"cylinder_r{round(radius_m * 1e3)}",
        class_label="mug",
        field=fields.CappedCylinder(radius_m, height_m),
        symmetric_about_z=True,
    )


BOX = ObjectModel(name="box", class_label="box", field=fields.Box([0.06, 0.06, 0.16]))
BOTTLE = objects.make("pet_bottle")  # the whole bottle (body, shoulder, neck), not its body


def _bottle_body_centre_m() -> float:
    """Where the bottle's body is centred on its axis (the origin is at half its height)."""
    d = BOTTLE.dims_m
    total = d["body_height_m"] + d["shoulder_height_m"] + d["neck_height_m"]
    return -total / 2 + d["body_height_m"] / 2


OBJECTS: dict[str, ObjectModel] = {
    "cylinder_r30": _cylinder(0.030, 0.080),
    "cylinder_r40": _cylinder(0.040, 0.095),
    "cylinder_r50": _cylinder(0.050, 0.120),
    "box_face": BOX,
    "box_edge": BOX,
    "box_corner": BOX,
    "bottle": BOTTLE,
}


def truth_pose(kind: str, rng: np.random.Generator) -> np.ndarray:
    """A ``tool_from_object`` of the given kind of grasp."""
    model = OBJECTS[kind]
    if kind == "bottle":  # held by its body only: the patch cannot tell its ends apart
        pose = synthetic.random_grasp_pose(model, rng, slide_m=0.005)
        return pose @ se3.make_pose(np.eye(3), [0.0, 0.0, -_bottle_body_centre_m()])
    if model.symmetric_about_z:
        return synthetic.random_grasp_pose(model, rng)
    tilt = se3.rotation_about(np.array([1.0, 0.0, 0.0]), np.radians(rng.uniform(-10, 10)))
    jitter = np.radians(rng.uniform(-3, 3))
    if kind == "box_face":
        rot = tilt @ se3.rotation_about(np.array([0.0, 0.0, 1.0]), jitter)
    elif kind == "box_edge":
        rot = tilt @ se3.rotation_about(np.array([0.0, 0.0, 1.0]), np.pi / 4 + jitter)
    else:  # box_corner: the body diagonal (1, 1, 1) of a cube-like end onto tool x
        diag = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
        axis = np.cross(diag, [1.0, 0.0, 0.0])
        rot = se3.rotation_about(axis, np.arccos(diag[0]) + jitter)
    return se3.make_pose(rot, [0.0, 0.0, rng.uniform(-0.01, 0.01)])


def bad_seed(model: ObjectModel, truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The truth turned 90 degrees about an object axis (80-degree tilt for bodies of
    revolution) and moved 3 mm."""
    if model.symmetric_about_z:
        return synthetic.tilted_seed(truth, 80.0, rng, offset_m=0.003)
    axis = np.eye(3)[rng.integers(3)]
    seed = truth @ se3.make_pose(se3.rotation_about(axis, np.pi / 2))
    shift = rng.normal(size=3)
    seed[:3, 3] += 0.003 * shift / np.linalg.norm(shift)
    return seed


def _solver(name: str, fld: fields.Field, fit_dims: tuple[str, ...] = ()) -> Any:
    if name == "lm":
        return LMSolver(fld)
    jit = "on" if jit_available("gcc") else "off"
    return IpoptSolver(fld, IpoptParams(jit=jit, fit_dims=fit_dims))


Judged = tuple[problem.FitResult, bool, bool, float]  # result, right, covered, CPU secs


def judged(
    fld: fields.Field,
    result: problem.FitResult,
    truth: np.ndarray,
    cpu: float,
    *,
    ends_alike: bool = False,
    points_in_tool: np.ndarray | None = None,
) -> Judged:
    """An estimate scored: right (``metrics.right``; along the directions observed, by
    the estimate or at the truth, when given the cloud ``points_in_tool``) and covered
    (``metrics.covered``); ``ends_alike``: the patch cannot tell the ends of the body of
    revolution apart."""
    return (
        result,
        metrics.right(fld, result, truth, ends_alike=ends_alike, points_in_tool=points_in_tool),
        metrics.covered(fld, result, truth, ends_alike=ends_alike),
        cpu,
    )


def _estimate_judged(
    est: PoseEstimator,
    kind: str,
    truth: np.ndarray,
    pts: np.ndarray,
    bub: np.ndarray,
    prior: np.ndarray | None,
) -> Judged:
    """One estimate of an ``OBJECTS[kind]`` cloud, timed (process CPU) and scored."""
    c0 = time.process_time()
    res = est.estimate(pts, bub, seed_tool_from_object=prior)
    cpu = time.process_time() - c0
    return judged(
        OBJECTS[kind].field, res, truth, cpu, ends_alike=kind == "bottle", points_in_tool=pts
    )


def summary(results: list[Judged], extra: dict[str, Any]) -> Row:
    """The verdict's quality over ``results``: right-and-ok, right-but-suspect (a share
    of the right answers), wrong-but-ok (``silent_wrong``), and the coverage of the
    stated 95% region (over the answers that state one, and over those ``ok`` or
    ``recovered``)."""
    statuses = [r.status for r, _, _, _ in results]
    cpu = [c for _, _, _, c in results]
    right_count = sum(1 for _, ok, _, _ in results if ok)
    stated = [cov for r, _, cov, _ in results if r.status not in ("no_patch", "failed")]
    vouched = [cov for r, _, cov, _ in results if r.status in GOOD]
    low, high = wilson_interval(sum(stated), len(stated))
    return {
        **extra,
        "default": "*" if extra.get("solver") == "ipopt" and not extra.get("fit_dims") else "",
        "cases": len(results),
        "success_rate": right_count / max(len(results), 1),
        "right_ok_rate": float(np.mean([ok and r.status in GOOD for r, ok, _, _ in results])),
        "right_suspect_share": sum(1 for r, ok, _, _ in results if ok and r.status not in GOOD)
        / max(right_count, 1),
        "silent_wrong": sum(1 for r, ok, _, _ in results if r.status in GOOD and not ok),
        "coverage95": float(np.mean(stated)) if stated else float("nan"),
        "coverage95_lo": low,
        "coverage95_hi": high,
        "coverage95_ok": float(np.mean(vouched)) if vouched else float("nan"),
        "region95_deg_median": median([r.region95_deg for r, _, _, _ in results]),
        "region95_mm_median": 1e3 * median([r.region95_m for r, _, _, _ in results]),
        "suspect_rate": float(np.mean([s == "suspect" for s in statuses])),
        "ok_rate": float(np.mean([s in GOOD for s in statuses])),
        "cpu_ms_median": 1e3 * median(cpu),
        "cpu_ms_p95": 1e3 * percentile(cpu, 95),
    }


def estimator_rows(
    kinds: list[str],
    solvers: list[str],
    noises: list[float],
    starts: list[str],
    n_cases: int,
    n_points: int,
) -> list[Row]:
    rows: list[Row] = []
    for kind in progress(kinds, "bench.pose_hard", label=lambda k: f"estimator, {k}"):
        model = OBJECTS[kind]
        for noise in noises:
            clouds = []
            for k in range(n_cases):
                rng = np.random.default_rng(1000 * k + round(noise * 1e5))
                truth = truth_pose(kind, rng)
                pts, bub = synthetic.grasp_cloud(
                    model, truth, n_points=n_points, noise_m=noise, rng=rng
                )
                clouds.append((truth, pts, bub, bad_seed(model, truth, rng)))
            for name in solvers:
                solver = _solver(name, model.field)
                if isinstance(solver, IpoptSolver):
                    solver.prepare(n_points)
                    solver.prepare(EstimatorParams().screen_points)
                est = PoseEstimator(
                    solver, EstimatorParams(), symmetric_about_z=model.symmetric_about_z
                )
                for start in starts:
                    results = []
                    for truth, pts, bub, seed in clouds:
                        est.reset()
                        prior = seed if start == "bad_seed" else None
                        if start == "track":
                            est.estimate(pts, bub)
                        results.append(_estimate_judged(est, kind, truth, pts, bub, prior))
                    rows.append(
                        summary(
                            results,
                            {
                                "kind": "hard",
                                "object": kind,
                                "solver": name,
                                "fit_dims": "",
                                "noise_mm": 1e3 * noise,
                                "points": n_points,
                                "start": start,
                            },
                        )
                    )
    return rows


def coverage_clouds(
    kind: str, noise: float, n_cases: int, n_points: int, first: int = COVERAGE_CLOUDS
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The coverage rows' clouds (``first`` on) of ``OBJECTS[kind]``: the truth
    (``tool_from_object``), the points, their bubbles and the seed (5 degrees and 2 mm
    off the truth)."""
    for k in range(first, first + n_cases):
        rng = np.random.default_rng(1000 * k + round(noise * 1e5))
        truth = truth_pose(kind, rng)
        pts, bub = synthetic.grasp_cloud(
            OBJECTS[kind], truth, n_points=n_points, noise_m=noise, rng=rng
        )
        yield truth, pts, bub, synthetic.tilted_seed(truth, 5.0, rng, offset_m=0.002)


def coverage_estimator(kind: str) -> PoseEstimator:
    """LM, one solve from the seed and the judgement per cloud (``search: false``)."""
    model = OBJECTS[kind]
    return PoseEstimator(
        _solver("lm", model.field),
        EstimatorParams(track=False, search=False),
        symmetric_about_z=model.symmetric_about_z,
    )


def coverage_rows(
    kinds: list[str],
    noises: list[float],
    n_cases: int,
    n_points: int,
    first: int = COVERAGE_CLOUDS,
) -> list[Row]:
    """The stated 95% region's coverage per shape and noise, on ``n_cases`` clouds each
    (the clouds ``first`` on, by default ``COVERAGE_CLOUDS``; keep them off the clouds
    the judgement was fitted on, 100-111 and 600-699),
    LM seeded 5 degrees and 2 mm off the truth: one solve and the judgement per cloud,
    never a search (``search: false``; the region is that of the minimum, whichever
    start reached it; the verdict is the judgement of that one solve)."""
    rows: list[Row] = []
    for kind in progress(kinds, "bench.pose_hard", label=lambda k: f"coverage, {k}"):
        est = coverage_estimator(kind)
        for noise in noises:
            results = [
                _estimate_judged(est, kind, truth, pts, bub, seed)
                for truth, pts, bub, seed in coverage_clouds(kind, noise, n_cases, n_points, first)
            ]
            rows.append(
                summary(
                    results,
                    {
                        "kind": "coverage",
                        "object": kind,
                        "solver": "lm",
                        "fit_dims": "",
                        "noise_mm": 1e3 * noise,
                        "points": n_points,
                        "start": "seed_5deg",
                    },
                )
            )
    return rows


def size_rows(offsets_mm: list[float], n_cases: int, n_points: int) -> list[Row]:
    """The model's radius is 40 mm; the true one is 40 + offset."""
    model = OBJECTS["cylinder_r40"]
    rows: list[Row] = []
    for fit in progress(((), ("radius",)), "bench.pose_hard", label=lambda f: f"size, fit {f}"):
        solver = _solver("ipopt", model.field, fit)
        est = PoseEstimator(solver, EstimatorParams(track=False))
        for off in offsets_mm:
            true = _cylinder(0.040 + off * 1e-3, 0.095)
            results, axis, offaxis, radius_err = [], [], [], []
            for k in range(n_cases):
                rng = np.random.default_rng(500 + k)
                truth = synthetic.random_grasp_pose(true, rng)
                pts, bub = synthetic.grasp_cloud(
                    true, truth, n_points=n_points, noise_m=0.001, rng=rng
                )
                seed = synthetic.tilted_seed(truth, 10.0, rng, offset_m=0.002)
                c0 = time.process_time()
                res = est.estimate(pts, bub, seed_tool_from_object=seed)
                cpu = time.process_time() - c0
                results.append(judged(true.field, res, truth, cpu, points_in_tool=pts))
                axis.append(
                    metrics.axis_error_deg(res.tool_from_object, truth, flip_symmetric=True)
                )
                offaxis.append(metrics.offaxis_error_m(res.tool_from_object, truth))
                if fit:
                    radius_err.append(abs(res.dims_m["radius_m"] - true.field.dims_m["radius_m"]))
            row = summary(
                results,
                {
                    "kind": "size",
                    "object": "cylinder_r40",
                    "solver": "ipopt",
                    "fit_dims": ",".join(fit),
                    "noise_mm": 1.0,
                    "points": n_points,
                    "start": "seed_10deg",
                    "size_offset_mm": off,
                },
            )
            row["axis_err_deg_median"] = median(axis)
            row["offaxis_err_mm_median"] = 1e3 * median(offaxis)
            row["radius_err_mm_median"] = 1e3 * median(radius_err) if fit else float("nan")
            rows.append(row)
    return rows


def degenerate_clouds() -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Clouds without the shape information to fix a pose, and the seed each gets."""
    rng = np.random.default_rng(3)
    plane = np.stack(
        [np.full(800, 0.03), rng.uniform(-0.02, 0.02, 800), rng.uniform(-0.03, 0.03, 800)], 1
    )
    plane[:, 0] += rng.normal(scale=0.0005, size=800)
    return {
        "identical": (np.tile([[0.04, 0.0, 0.01]], (3000, 1)), None),
        "collinear": (np.outer(np.linspace(-0.03, 0.03, 500), [0.0, 0.6, 0.8]), None),
        "planar_seeded": (plane, np.eye(4)),
        "empty": (np.zeros((0, 3)), None),
        "all_nan": (np.full((500, 3), np.nan), None),
    }


def degenerate_rows(solvers: list[str]) -> list[Row]:
    rows: list[Row] = []
    for name in solvers:
        est = PoseEstimator(_solver(name, BOX.field), EstimatorParams(), symmetric_about_z=False)
        for label, (pts, seed) in degenerate_clouds().items():
            est.reset()
            c0 = time.process_time()
            res = est.estimate(pts, seed_tool_from_object=seed)
            cpu = time.process_time() - c0
            # Nothing is right without a prior; with one (the planar patch), the answer
            # may be right along what the patch observes: the seed's face.
            scored = (
                judged(BOX.field, res, seed, cpu, points_in_tool=pts)
                if seed is not None
                else (res, False, False, cpu)
            )
            rows.append(
                {
                    **summary(
                        [scored],
                        {
                            "kind": "degenerate",
                            "object": f"box/{label}",
                            "solver": name,
                            "fit_dims": "",
                            "points": len(pts),
                            "start": "seeded" if seed is not None else "cold",
                        },
                    ),
                    "status": res.status,
                    "message": res.message[:60],
                }
            )
    return rows


def run(quick: bool) -> list[Row]:
    one_core()
    if quick:
        rows = estimator_rows(["cylinder_r40", "box_edge"], ["lm"], [0.001], ["cold"], 2, 1000)
        rows += estimator_rows(["bottle"], ["lm"], [0.001], ["cold"], 2, 1000)
        rows += size_rows([5.0], 1, 1000)
        rows += coverage_rows(["box_corner"], [0.003], 3, 1000)
        return rows + degenerate_rows(["lm"])
    kinds = list(OBJECTS)
    rows = estimator_rows(kinds, ["lm", "ipopt"], [0.001], ["cold", "bad_seed", "track"], 8, 3000)
    rows += estimator_rows(
        kinds, ["lm", "ipopt"], [0.0005, 0.002, 0.003], ["cold", "bad_seed"], 8, 3000
    )
    # Cold-start and tracking time at 10k points, by solver.
    rows += estimator_rows(["cylinder_r40"], ["lm", "ipopt"], [0.001], ["cold", "track"], 6, 10000)
    rows += size_rows([1.0, 2.0, 4.0, 8.0], 6, 3000)
    rows += coverage_rows(kinds, [0.0005, 0.001, 0.002, 0.003], 200, 3000)
    return rows + degenerate_rows(["lm", "ipopt"])


COLUMNS = [
    "kind",
    "object",
    "solver",
    "fit_dims",
    "noise_mm",
    "points",
    "start",
    "size_offset_mm",
    "cases",
    "default",
    "success_rate",
    "right_ok_rate",
    "right_suspect_share",
    "silent_wrong",
    "coverage95",
    "coverage95_lo",
    "coverage95_hi",
    "coverage95_ok",
    "region95_deg_median",
    "region95_mm_median",
    "suspect_rate",
    "axis_err_deg_median",
    "radius_err_mm_median",
    "cpu_ms_median",
    "cpu_ms_p95",
    "status",
]

if __name__ == "__main__":
    main("pose_hard", run, columns=COLUMNS)
