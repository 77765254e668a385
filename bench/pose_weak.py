"""Along the weakest rotation: whether the stated spread is the errors' own, and what
``ok`` would need there.

``ok`` asks that an answer be within 2 degrees and 2 mm of the truth with 99.5%
probability under its stated uncertainty (``judge.within_tolerance``). Where one
rotation is weakly determined (the rotation about a box's body diagonal when it is
squeezed over its corners) right answers are ``suspect`` either because the stated
spread along that rotation is wider than the errors (a calibration fault, fixable) or
because it is as wide as they are (then no verdict can call them ``ok`` without calling
the wrong ones ``ok`` too). These rows tell the two apart, on the clouds and estimates
of ``bench.pose_hard``'s coverage rows (LM, one solve from 5 degrees off, the
judgement):

- ``weak_sd_deg_median``: the stated standard deviation along the weakest rotation
  (the largest eigenvalue of the covariance's rotation block);
- ``weak_err_deg_rms``: the answers' error along that direction (to the truth, up to
  the object's symmetry turns, along the observed directions);
- ``weak_z_rms``: the error in units of the stated deviation (1 when calibrated; under 1:
  the spread stated too wide);
- ``ok_at_{2,3,4}deg``: the share of the right answers whose probability within that
  rotation (and 2 mm) is at least ``judge.CONFIDENCE``: ``ok`` at that tolerance;
- ``silent_wrong``: wrong answers ``ok`` or ``recovered``;
- ``wrong_p_max``: the highest such probability (at 2 degrees) of a wrong answer, and
  ``right_above_wrong``: the share of the right answers at or above it, the most any
  threshold on that probability can call ``ok`` without calling a wrong one ``ok``.

    python -m bench.pose_weak [--quick] [--json]
"""

from __future__ import annotations

import numpy as np

from bench.common import Row, main, median, one_core, progress
from bench.pose_hard import OBJECTS, coverage_clouds, coverage_estimator
from geometry import se3
from perception.pose import judge, metrics
from perception.pose.problem import FitResult, characteristic_length
from perception.pose.symmetry import symmetry_rotations

TOLERANCES_DEG = (2.0, 3.0, 4.0)


def weakest(kind: str, result: FitResult, truth: np.ndarray) -> tuple[float, float, list[float]]:
    """The stated deviation along the weakest rotation (degrees), the error along it
    (degrees, signed), and the probability within each of ``TOLERANCES_DEG`` (and 2 mm)."""
    fld = OBJECTS[kind].field
    unc = judge.from_covariance(result.covariance, characteristic_length(fld))
    # The truth's nearest symmetric copy, in the region's own metric (as metrics.covered).
    coords = min(
        (
            judge.observed_difference(
                unc, result.object_from_tool, se3.make_pose(t) @ se3.invert(truth)
            )
            for t in symmetry_rotations(fld)
        ),
        key=lambda c: judge.within_region(unc, c),
    )
    twist = (unc.basis @ coords) * unc.scale
    vals, vecs = np.linalg.eigh(result.covariance[3:, 3:])
    probability = [judge.within_tolerance(unc, tol, 0.002) for tol in TOLERANCES_DEG]
    return (
        float(np.degrees(np.sqrt(max(vals[-1], 0.0)))),
        float(np.degrees(vecs[:, -1] @ twist[3:])),
        probability,
    )


def weak_rows(kinds: list[str], noises: list[float], n_cases: int, n_points: int) -> list[Row]:
    rows: list[Row] = []
    for kind in progress(kinds, "bench.pose_weak", label=str):
        est = coverage_estimator(kind)
        for noise in noises:
            sd, err, prob, right, ok = [], [], [], [], []
            for truth, pts, bub, seed in coverage_clouds(kind, noise, n_cases, n_points):
                result = est.estimate(pts, bub, seed_tool_from_object=seed)
                s, e, p = weakest(kind, result, truth)
                sd.append(s)
                err.append(e)
                prob.append(p)
                right.append(metrics.right(OBJECTS[kind].field, result, truth, points_in_tool=pts))
                ok.append(result.status in ("ok", "recovered"))
            sds, errs, probs = np.array(sd), np.array(err), np.array(prob)
            hit, miss = np.array(right), ~np.array(right)
            wrong_max = float(probs[miss, 0].max()) if miss.any() else float("nan")
            row: Row = {
                "object": kind,
                "noise_mm": 1e3 * noise,
                "points": n_points,
                "cases": n_cases,
                "right": int(hit.sum()),
                "right_ok": int(np.sum(hit & np.array(ok))),
                "silent_wrong": int(np.sum(miss & np.array(ok))),
                "weak_sd_deg_median": median(list(sds)),
                "weak_err_deg_rms": float(np.sqrt(np.mean(errs**2))),
                "weak_z_rms": float(np.sqrt(np.mean((errs / np.maximum(sds, 1e-12)) ** 2))),
                "wrong_p_max": wrong_max,
                "right_above_wrong": float(np.mean(probs[hit, 0] >= wrong_max))
                if miss.any() and hit.any()
                else float("nan"),
            }
            for j, tol in enumerate(TOLERANCES_DEG):
                row[f"ok_at_{tol:g}deg"] = (
                    float(np.mean(probs[hit, j] >= judge.CONFIDENCE)) if hit.any() else float("nan")
                )
            rows.append(row)
    return rows


def run(quick: bool) -> list[Row]:
    one_core()
    if quick:
        return weak_rows(["box_corner"], [0.003], 3, 1000)
    return weak_rows(["box_corner"], [0.001, 0.002, 0.003], 100, 3000) + weak_rows(
        ["box_corner"], [0.003], 40, 10000
    )


COLUMNS = [
    "object",
    "noise_mm",
    "points",
    "cases",
    "right",
    "right_ok",
    "silent_wrong",
    "weak_sd_deg_median",
    "weak_err_deg_rms",
    "weak_z_rms",
    "ok_at_2deg",
    "ok_at_3deg",
    "ok_at_4deg",
    "wrong_p_max",
    "right_above_wrong",
]

if __name__ == "__main__":
    main("pose_weak", run, columns=COLUMNS)
