"""The LM fit and the robust estimator on synthetic grasp clouds, and the hard cases."""

from __future__ import annotations

import numpy as np
import pytest

from geometry import fields, se3
from geometry.objects import ObjectModel
from perception.pose import metrics, problem, synthetic
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.lm import LMSolver
from runtime.params import build_params

CYL = ObjectModel(
    name="cylinder",
    class_label="mug",
    field=fields.CappedCylinder(0.04, 0.095),
    symmetric_about_z=True,
)


def _case(seed: int, model: ObjectModel = CYL, n: int = 1500, noise_m: float = 0.001):
    rng = np.random.default_rng(seed)
    truth = synthetic.random_grasp_pose(model, rng)
    pts, bubble = synthetic.grasp_cloud(model, truth, n_points=n, noise_m=noise_m, rng=rng)
    return rng, truth, pts, bubble


def _errors(result: problem.FitResult, truth: np.ndarray) -> tuple[float, float]:
    return (
        metrics.axis_error_deg(result.tool_from_object, truth, flip_symmetric=True),
        metrics.offaxis_error_m(result.tool_from_object, truth),
    )


def test_synthetic_cloud_lies_on_the_surface() -> None:
    _, truth, pts, bubble = _case(0, noise_m=0.0)
    assert len(pts) == 1500 and set(np.unique(bubble)) == {0, 1}
    inside_obj = se3.transform_points(se3.invert(truth), pts)
    np.testing.assert_allclose(CYL.field.value(inside_obj), 0.0, atol=1e-9)
    # Left bubble (0) is at tool +x.
    assert pts[bubble == 0, 0].mean() > 0 > pts[bubble == 1, 0].mean()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_lm_recovers_known_pose_from_a_tilted_seed(seed: int) -> None:
    rng, truth, pts, _ = _case(seed)
    start = synthetic.tilted_seed(truth, 20.0, rng, offset_m=0.005)
    result = LMSolver(CYL.field).solve(pts, se3.invert(start))
    axis_deg, off_m = _errors(result, truth)
    assert axis_deg < 1.0 and off_m < 0.001
    assert result.residual_rms_m < 0.0015
    # Side patches of a plain cylinder: slide along and yaw about its axis are invisible.
    assert (
        result.observable == (True, True, False, True, True, False) or result.observable[5] is False
    )


def test_lm_keeps_unobservable_directions_at_the_seed() -> None:
    rng, truth, _, _ = _case(4)
    # Only the side surface, well away from the caps: tz and rz carry no information.
    side = fields.CappedCylinder(0.04, 0.095).sample_surface(4000, rng)
    side = side[np.abs(side[:, 2]) < 0.03][:1000]
    pts = se3.transform_points(truth, side)
    start = truth @ se3.make_pose(se3.rotation_about(np.array([0, 0, 1.0]), 0.4), [0, 0, 0.01])
    result = LMSolver(CYL.field).solve(pts, se3.invert(start))
    assert result.observable == (True, True, False, True, True, False)
    # The yaw and slide of the seed survive unchanged: the step never moved them.
    rel = se3.invert(start) @ result.tool_from_object
    np.testing.assert_allclose(rel, np.eye(4), atol=1e-6)


def test_estimator_cold_start_and_tracking() -> None:
    est = PoseEstimator(LMSolver(CYL.field), EstimatorParams(noise_m=0.001))
    _, truth, pts, bubble = _case(5)
    first = est.estimate(pts, bubble)
    assert first.status in ("ok", "recovered")
    assert max(_errors(first, truth)[0], 0.0) < 1.0
    assert first.seeds_tried > 1  # a cold start checks its minimum against the turns
    # Tracking: the next call warm-starts from the last estimate (one solve).
    again = est.estimate(pts, bubble)
    assert again.status == "ok" and again.seeds_tried == 1


def test_estimator_recovers_from_a_wrong_minimum() -> None:
    # A seed 90 degrees off: LM lands in a wrong minimum; the turns find the right one.
    est = PoseEstimator(LMSolver(CYL.field), EstimatorParams(noise_m=0.001, track=False))
    _, truth, pts, bubble = _case(6)
    wrong = truth @ se3.make_pose(se3.rotation_about(np.array([1.0, 0, 0]), np.pi / 2))
    result = est.estimate(pts, bubble, seed_tool_from_object=wrong)
    assert result.status in ("ok", "recovered")
    assert _errors(result, truth)[0] < 1.0


@pytest.mark.parametrize(
    ("label", "points"),
    [
        ("empty", np.zeros((0, 3))),
        ("three", np.array([[0.04, 0, 0], [-0.04, 0, 0], [0.04, 0.01, 0]])),
        ("all_nan", np.full((500, 3), np.nan)),
    ],
)
def test_degenerate_patches_give_no_patch(label: str, points: np.ndarray) -> None:
    est = PoseEstimator(LMSolver(CYL.field))
    result = est.estimate(points)
    assert result.status == "no_patch", label
    assert np.all(np.isfinite(result.tool_from_object))
    assert result.observable == (False,) * 6 and result.residual_rms_m == 0.0


def test_huge_offset_and_near_180_degree_seed() -> None:
    est = PoseEstimator(LMSolver(CYL.field), EstimatorParams(noise_m=0.001, track=False))
    _, truth, pts, bubble = _case(8)
    far = truth.copy()
    far[:3, 3] += [50.0, -30.0, 80.0]
    result = est.estimate(pts, bubble, seed_tool_from_object=far)
    assert np.all(np.isfinite(result.tool_from_object))
    assert _errors(result, truth)[1] < 0.002
    flipped = truth @ se3.make_pose(se3.rotation_about(np.array([1.0, 1.0, 0]), np.pi - 1e-6))
    result = est.estimate(pts, bubble, seed_tool_from_object=flipped)
    assert np.all(np.isfinite(result.tool_from_object))
    assert _errors(result, truth)[0] < 1.0


def test_nan_rows_are_dropped() -> None:
    _, truth, pts, bubble = _case(9)
    dirty = pts.copy()
    dirty[::7] = np.nan
    est = PoseEstimator(LMSolver(CYL.field), EstimatorParams(noise_m=0.001))
    result = est.estimate(dirty, bubble)
    assert result.points_used == int(np.all(np.isfinite(dirty), axis=1).sum())
    assert _errors(result, truth)[0] < 1.0


def test_solver_errors_become_failed_status() -> None:
    class Broken:
        name = "broken"
        field = CYL.field

        def solve(self, points, seed):  # noqa: ANN001, ANN201
            raise np.linalg.LinAlgError("singular")

    _, _, pts, bubble = _case(10)
    result = PoseEstimator(Broken()).estimate(pts, bubble)
    assert result.status == "failed" and "singular" in result.message
    assert np.all(np.isfinite(result.tool_from_object)) and np.isfinite(result.residual_rms_m)


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="noise_m"):
        build_params(EstimatorParams, {"noise_m": -1.0})
    with pytest.raises(ValueError, match="min_points"):
        build_params(EstimatorParams, {"min_points": 2})
