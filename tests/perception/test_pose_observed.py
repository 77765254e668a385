"""Scoring an estimate along what was observed: a recorded grasp whose answer differs
from the truth only where neither it nor the patch can see is right, a direction an
estimate wrongly calls unobservable still counts, and one outlier observes nothing."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from bench import pose_hard
from geometry import objects, se3
from perception.pose import judge, metrics
from perception.pose.estimator import PoseEstimator
from perception.pose.lm import LMSolver
from perception.pose.problem import FitResult, residuals

GOOD = ("ok", "recovered")
#: 1000 points of the cloud ``bench.worlds`` extracts from its grasp 6 on ``world.sim``
#: (the square bottle held across two faces, rolled 8.6 degrees within them, 3000
#: points at the held frame), and the world's ``tool_from_object`` then.
CLOUD = Path(__file__).parent / "data" / "square_bottle_faces_sim.npz"


def _recorded() -> tuple[objects.ObjectModel, np.ndarray, np.ndarray, np.ndarray]:
    data = np.load(CLOUD)
    model = objects.make("square_bottle")
    pts = data["points_in_tool"].astype(np.float64)
    return model, pts, data["bubble"], data["tool_from_object"]


def test_a_square_bottle_off_only_within_the_held_faces_is_right() -> None:
    model, pts, bubble, truth = _recorded()
    est = PoseEstimator(LMSolver(model.field), symmetric_about_z=model.symmetric_about_z)
    result = est.estimate(pts, bubble)
    assert result.status in GOOD, result.message
    # The faces the jaws hold are object +-y: the slide and turn within them are not seen.
    assert result.observable == (False, True, False, True, False, True)
    # No estimator could do better along them: the answer fits the cloud as well as the
    # truth does.
    rms_est = np.sqrt(np.mean(residuals(model.field, result.object_from_tool, pts) ** 2))
    rms_true = np.sqrt(np.mean(residuals(model.field, se3.invert(truth), pts) ** 2))
    assert rms_est <= 1.05 * rms_true
    angle, offset = metrics.observed_error(model.field, result, truth, pts, ends_alike=True)
    assert angle < 0.5 and offset < 0.0005, (angle, offset)
    assert metrics.right(model.field, result, truth, ends_alike=True, points_in_tool=pts)


def test_an_error_where_the_patch_sees_counts_whatever_the_estimate_claims() -> None:
    model, pts, _, truth = _recorded()
    at_truth = se3.invert(truth)
    blind = replace(
        _fit(model, pts, at_truth),
        observable=(False,) * 6,  # an estimate that claims to observe nothing
    )
    for axis, seen in ((1, True), (0, False), (2, False)):
        moved = np.zeros(6)
        moved[axis] = 0.005  # 5 mm along one axis of the object frame
        wrong = replace(blind, object_from_tool=se3.exp_se3(moved) @ at_truth)
        assert metrics.right(model.field, wrong, truth, points_in_tool=pts) is not seen, axis
    turned = np.zeros(6)
    turned[3] = np.radians(5.0)  # a tilt out of the held faces: seen
    wrong = replace(blind, object_from_tool=se3.exp_se3(turned) @ at_truth)
    assert not metrics.right(model.field, wrong, truth, points_in_tool=pts)


def test_a_slide_seen_through_one_outlier_is_not_observed() -> None:
    # Cloud 603 of bench.pose_calib's fit set: a 30 mm cylinder at 3 mm noise, its patch
    # as long as the body. Only points past the rims see the slide along the axis (2% of
    # them); at the truth one outlier thrown 12 mm past a rim made it "observed", so the
    # answer, `ok` with the slide unobservable and 2.15 mm off along it, was scored wrong.
    kind = "cylinder_r30"
    fld = pose_hard.OBJECTS[kind].field
    truth, pts, bubble, seed = next(pose_hard.coverage_clouds(kind, 0.003, 1, 3000, first=603))
    result = pose_hard.coverage_estimator(kind).estimate(pts, bubble, seed_tool_from_object=seed)
    assert judge.uncertainty(fld, se3.invert(truth), pts).observable == result.observable
    assert result.observable == (True, True, False, True, True, False)
    assert result.status == "ok", result.message
    assert metrics.right(fld, result, truth, points_in_tool=pts)


def _fit(model: objects.ObjectModel, pts: np.ndarray, pose: np.ndarray) -> FitResult:
    return LMSolver(model.field).solve(pts, pose)
