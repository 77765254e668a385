"""The judgement of an estimate: its uncertainty, what it holds against an answer and what
it only reports."""

from __future__ import annotations

import numpy as np
import pytest

from bench import pose_hard
from geometry import fields, se3
from geometry.objects import ObjectModel
from perception.pose import cloud, judge, metrics, symmetry, synthetic
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.icp import IcpSolver
from perception.pose.ipopt import IpoptParams, IpoptSolver
from perception.pose.lm import LMSolver
from perception.pose.problem import characteristic_length, residuals, residuals_and_jacobian

CYL = ObjectModel(
    name="cylinder",
    class_label="mug",
    field=fields.CappedCylinder(0.04, 0.095),
    symmetric_about_z=True,
)
GOOD = ("ok", "recovered")


def _estimate(kind: str, k: int, noise_m: float, n: int = 3000, **params: object):
    model = pose_hard.OBJECTS[kind]
    rng = np.random.default_rng(700 + k)
    truth = pose_hard.truth_pose(kind, rng)
    pts, bubble = synthetic.grasp_cloud(model, truth, n_points=n, noise_m=noise_m, rng=rng)
    est = PoseEstimator(
        LMSolver(model.field),
        EstimatorParams(track=False, **params),  # type: ignore[arg-type]
        symmetric_about_z=model.symmetric_about_z,
    )
    return model, truth, est.estimate(pts, bubble)


def test_every_estimate_carries_its_uncertainty() -> None:
    model, truth, result = _estimate("cylinder_r40", 0, 0.001)
    assert result.status in GOOD and metrics.right(model.field, result, truth)
    cov = result.covariance
    assert cov.shape == (6, 6) and np.all(np.isfinite(cov))
    np.testing.assert_allclose(cov, cov.T, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-15)
    # Zero along what the patch cannot see: the cylinder's yaw.
    assert not result.observable[5] and abs(cov[5, 5]) < 1e-30
    assert 0.0 < result.region95_deg < 2.0 and 0.0 < result.region95_m < 0.002


def test_the_95_percent_region_usually_holds_the_truth() -> None:
    """Not the calibration itself (bench.pose_hard measures it per shape and noise): the
    stated region holds the truth most of the time on easy clouds."""
    held = []
    for k in range(12):
        model, truth, result = _estimate("cylinder_r50", k, 0.0005)
        held.append(metrics.covered(model.field, result, truth))
    assert np.mean(held) >= 0.75, held


@pytest.mark.parametrize("noise_m", [0.002, 0.003])
def test_small_patches_at_high_noise_are_never_wrong_and_ok(noise_m: float) -> None:
    """Shallow contacts (2 mm deep, 300 points) at 2-3 mm noise: the axis is loosely
    determined; an answer that is off is never called ``ok``."""
    est = PoseEstimator(LMSolver(CYL.field), EstimatorParams(track=False))
    for k in range(6):
        rng = np.random.default_rng(900 + k)
        truth = synthetic.random_grasp_pose(CYL, rng)
        pts, bubble = synthetic.grasp_cloud(
            CYL, truth, n_points=300, noise_m=noise_m, rng=rng, depth_m=0.002
        )
        result = est.estimate(pts, bubble)
        if result.status in GOOD:
            assert metrics.right(CYL.field, result, truth), (k, result.region95_deg)
        else:
            assert result.message


def test_a_bottle_end_over_end_is_reported_not_suspect() -> None:
    """The whole bottle held by its body: the patch cannot tell its ends apart. The
    answers agree on the axis and the position across it, and are not held suspect for
    the flip."""
    statuses, flips = [], 0
    for k in range(4):
        model, truth, result = _estimate("bottle", k, 0.001, n=2000)
        statuses.append(result.status)
        assert "another minimum" not in result.message, result.message
        if result.status in GOOD:
            assert metrics.right(model.field, result, truth) or "end over end" in (
                result.alternatives
            )
        flips += "end over end" in result.alternatives
    assert statuses.count("suspect") <= 1, statuses


def test_box_faces_are_not_suspect_for_what_they_cannot_see() -> None:
    """Two parallel faces do not fix the slide or the turn within them: reported as
    unobservable, never a reason for ``suspect``."""
    for k in range(4):
        model, truth, result = _estimate("box_face", k, 0.001)
        assert result.status in GOOD, result.message
        assert metrics.right(model.field, result, truth)
        assert not all(result.observable)


@pytest.mark.parametrize("name", ["icp", "ipopt_loose"])
def test_the_verdict_does_not_depend_on_the_solver(name: str) -> None:
    """ICP and IPOPT at a loose tolerance stop short of the minimum of the fit; the
    judgement takes them the rest of the way, so their right answers from a near seed
    are ``ok`` after one solve, as LM's are (on main ICP's were searched and some
    ``suspect``)."""
    model = pose_hard.OBJECTS["cylinder_r40"]
    solver = (
        IcpSolver(model.field)
        if name == "icp"
        else IpoptSolver(model.field, IpoptParams(jit="off", tol=1e-4))
    )
    est = PoseEstimator(solver, EstimatorParams(track=False))
    for k in range(4):
        rng = np.random.default_rng(800 + k)
        truth = pose_hard.truth_pose("cylinder_r40", rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=1500, noise_m=0.001, rng=rng)
        seed = synthetic.tilted_seed(truth, 3.0, rng, offset_m=0.002)
        result = est.estimate(pts, bubble, seed_tool_from_object=seed)
        assert result.status == "ok", (k, result.message)
        assert result.seeds_tried == 1
        assert metrics.right(model.field, result, truth)


@pytest.mark.parametrize("kind", ["cylinder_r30", "bottle"])
def test_the_95_percent_region_holds_the_truth_under_oblique_ray_noise(kind: str) -> None:
    """3 mm of noise along the cameras' oblique rays biases a fit on a curved surface by
    up to a few times the statistical spread (second order in the noise: more points do
    not remove it); the judgement predicts the bias from the rays and undoes it. On
    main the 95% region held the truth in 9 (cylinder) and 8 (bottle) of these 12."""
    model = pose_hard.OBJECTS[kind]
    est = PoseEstimator(
        LMSolver(model.field),
        EstimatorParams(track=False),
        symmetric_about_z=model.symmetric_about_z,
    )
    held = []
    for k in range(12):
        rng = np.random.default_rng(300 + k)
        truth = pose_hard.truth_pose(kind, rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=2000, noise_m=0.003, rng=rng)
        seed = synthetic.tilted_seed(truth, 3.0, rng, offset_m=0.002)
        result = est.estimate(pts, bubble, seed_tool_from_object=seed)
        held.append(metrics.covered(model.field, result, truth, ends_alike=kind == "bottle"))
    assert sum(held) >= 11, held


def test_the_camera_rays_come_from_the_points_alone() -> None:
    """Each bubble's camera is placed from its own points; the rays agree with those the
    synthetic cloud put its noise along."""
    model = pose_hard.OBJECTS["cylinder_r40"]
    truth = pose_hard.truth_pose("cylinder_r40", np.random.default_rng(3))
    clean, bubble = synthetic.grasp_cloud(
        model, truth, n_points=500, noise_m=0.0, rng=np.random.default_rng(5)
    )
    nudged, _ = synthetic.grasp_cloud(
        model, truth, n_points=500, noise_m=1e-6, rng=np.random.default_rng(5)
    )
    true_rays = nudged - clean
    true_rays /= np.linalg.norm(true_rays, axis=1, keepdims=True)
    rays = cloud.camera_rays(clean, bubble)
    assert rays is not None
    angle = np.degrees(np.arccos(np.clip(np.abs(np.sum(rays * true_rays, axis=1)), 0.0, 1.0)))
    assert angle.max() < 0.5
    assert cloud.camera_rays(clean, None) is None
    assert cloud.camera_rays(clean, np.full(len(clean), 2, np.uint8)) is None


def test_a_box_corner_at_3_mm_is_observed_and_its_noise_measured() -> None:
    """A box squeezed over its corners at 3 mm noise along the rays: the noise crosses an
    edge almost everywhere (1-3% of the points are smooth across it), yet each of the
    three faces is seen through a third of the points, so all six directions are
    observed (1-2 of 6 before), and the noise measured along the rays is that of the
    residual at the truth (1.0 mm measured for 1.6 mm before: a ball of neighbours cut
    the noise off). The answers are right, finite, and held against nothing but the
    width of their region (the rotation about the body diagonal)."""
    model = pose_hard.OBJECTS["box_corner"]
    est = PoseEstimator(
        LMSolver(model.field), EstimatorParams(track=False), symmetric_about_z=False
    )
    for k in range(4):
        rng = np.random.default_rng(900 + k)
        truth = pose_hard.truth_pose("box_corner", rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=3000, noise_m=0.003, rng=rng)
        at_truth = judge.uncertainty(
            model.field, se3.invert(truth), pts, rays_in_tool=cloud.camera_rays(pts, bubble)
        )
        assert all(at_truth.observable), at_truth.observable
        r = residuals(model.field, se3.invert(truth), pts)
        noise = cloud.estimate_noise_m(pts, cloud.camera_rays(pts, bubble))
        assert 0.85 < float(np.sqrt(np.mean(r * r))) / noise < 1.15, noise
        result = est.estimate(pts, bubble)
        assert np.all(np.isfinite(result.object_from_tool)) and np.all(
            np.isfinite(result.covariance)
        )
        assert metrics.right(model.field, result, truth, points_in_tool=pts)
        assert all(result.observable)
        if result.status == "suspect":
            assert result.message.startswith("not determined to") and ";" not in result.message


def test_the_95_percent_region_holds_a_box_corner_at_3_mm() -> None:
    """A box squeezed over its corners at 3 mm noise along the rays: the region over the
    observed directions, at the minimum of the fit with the predicted bias undone, holds
    the truth in 7 or more of these 8 (6 when the bias was undone by one step from the
    minimum and its error taken along the shift alone; 3 with ``J^T J`` for the
    curvature)."""
    model = pose_hard.OBJECTS["box_corner"]
    turns = symmetry.symmetry_rotations(model.field)
    held = 0
    for k in range(8):
        rng = np.random.default_rng(900 + k)
        truth = pose_hard.truth_pose("box_corner", rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=3000, noise_m=0.003, rng=rng)
        fit = LMSolver(model.field).solve(pts, se3.invert(truth))
        unc = judge.uncertainty(
            model.field, fit.object_from_tool, pts, rays_in_tool=cloud.camera_rays(pts, bubble)
        )
        assert np.all(np.isfinite(unc.covariance)) and unc.basis.shape[1] > 0
        at = se3.exp_se3(unc.correction) @ fit.object_from_tool
        held += (
            min(
                judge.within_region(
                    unc, judge.observed_difference(unc, at, se3.make_pose(t) @ se3.invert(truth))
                )
                for t in turns
            )
            <= 1.0
        )
    assert held >= 7, held


def test_within_tolerance_is_the_probability_of_the_gaussian() -> None:
    """One rotation with a 1 degree standard deviation, all else tight: the truth lies
    within 2 degrees with probability erf(2 / sqrt 2) = 0.9545; within 1 degree, 0.6827;
    a 1 mm spread across three axes is within 2 mm with the chi-square(3) probability at 4."""
    length = 0.1
    cov = np.diag([1e-14] * 3 + [np.radians(1.0) ** 2, 1e-14, 1e-14])
    unc = judge.from_covariance(cov, length)
    assert judge.within_tolerance(unc, 2.0, 0.002) == pytest.approx(0.9545, abs=0.01)
    assert judge.within_tolerance(unc, 1.0, 0.002) == pytest.approx(0.6827, abs=0.015)
    cov = np.diag([1e-6] * 3 + [1e-14] * 3)
    unc = judge.from_covariance(cov, length)
    assert judge.within_tolerance(unc, 2.0, 0.002) == pytest.approx(0.7385, abs=0.015)


def test_a_box_corner_at_2_mm_is_ok_when_within_the_tolerance() -> None:
    """A box squeezed over its corners at 2 mm noise: its 95% region spans 1.9-3.4
    degrees over six directions (along the weak rotation about the body diagonal), and
    the truth lies within 2 degrees with probability 0.975-1; the answers are right, and
    ``ok`` exactly when that probability is at least ``judge.CONFIDENCE``, a region wider
    than 2 degrees included (every such answer was ``suspect`` when ``ok`` needed the
    region's extent within the tolerance)."""
    model = pose_hard.OBJECTS["box_corner"]
    length = characteristic_length(model.field)
    est = PoseEstimator(
        LMSolver(model.field), EstimatorParams(track=False), symmetric_about_z=False
    )
    wide_ok = 0
    for k in range(8):
        rng = np.random.default_rng(900 + k)
        truth = pose_hard.truth_pose("box_corner", rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=3000, noise_m=0.002, rng=rng)
        result = est.estimate(pts, bubble, seed_tool_from_object=truth)
        assert metrics.right(model.field, result, truth, points_in_tool=pts)
        unc = judge.from_covariance(result.covariance, length)
        inside = judge.within_tolerance(unc, 2.0, 0.002)
        assert (result.status in GOOD) == (inside >= judge.CONFIDENCE), (inside, result.message)
        wide_ok += result.status in GOOD and result.region95_deg > 2.0
    assert wide_ok >= 1


def test_a_box_corner_at_2_mm_is_not_held_to_the_allowance_fitted_at_3_mm() -> None:
    """The allowance for the rays' bias each face mispredicts (``judge.FACE_ERROR``) was
    fitted at a box's corner at 3 mm noise; the misprediction grows with the noise, so
    at 2 mm the same share made the region too wide along the weak rotation (errors
    0.76 of the stated spread there over 100 clouds, 98 of 100 regions holding the truth)
    and a third of the right answers ``suspect``. In proportion to the ray noise: these
    12 clouds at 2 mm, each one LM solve from 5 degrees off, are all right, and 10 or
    more ``ok`` (9 with the share fixed; 11 when the curvature's axes turned with the
    solver's stop, before the shares were refitted; the eleventh is within 0.002 of
    ``judge.CONFIDENCE``)."""
    model = pose_hard.OBJECTS["box_corner"]
    est = PoseEstimator(
        LMSolver(model.field), EstimatorParams(track=False, search=False), symmetric_about_z=False
    )
    ok = 0
    for k in range(900, 912):
        rng = np.random.default_rng(k)
        truth = pose_hard.truth_pose("box_corner", rng)
        pts, bubble = synthetic.grasp_cloud(model, truth, n_points=3000, noise_m=0.002, rng=rng)
        seed = synthetic.tilted_seed(truth, 5.0, rng, offset_m=0.002)
        result = est.estimate(pts, bubble, seed_tool_from_object=seed)
        assert metrics.right(model.field, result, truth, points_in_tool=pts), k
        ok += result.status in GOOD
    assert ok >= 10, ok


def test_a_box_corner_at_3_mm_with_10k_points_is_never_wrong_and_ok() -> None:
    """``bench.pose_weak``'s row at 10k points (the node's ``max_points``): cloud 213,
    one LM solve from 5 degrees off, 2.9 degrees off along the weak rotation (the one
    about the box's body diagonal). The cost is flatter along it than a fifth of
    ``J^T J`` says (measured 0.22), and the spread was stated with half of it, the floor
    the bias correction's Newton steps need (``judge.CURVATURE_FLOOR``): 0.68 degree, and
    within 2 degrees with probability 0.9965, ``ok`` on the code before. Over 20 other
    noise draws on the same pose the answers' scatter along that rotation was 1.9 times
    the sandwich's."""
    ((truth, pts, bubble, seed),) = pose_hard.coverage_clouds(
        "box_corner", 0.003, 1, 10000, first=213
    )
    result = pose_hard.coverage_estimator("box_corner").estimate(
        pts, bubble, seed_tool_from_object=seed
    )
    right = metrics.right(pose_hard.OBJECTS["box_corner"].field, result, truth, points_in_tool=pts)
    assert right or result.status not in GOOD, result.status


def test_the_measured_curvature_does_not_depend_on_the_axes_it_is_given() -> None:
    """``judge.curvature`` is a secant along each direction, not a quadratic form: along
    axes that are turned, it measured another curvature (the judgement's axes came from
    an SVD whose axes turn freely). Measured along Gauss-Newton's eigenvectors, turning
    the axes it is given turns the result with them."""
    ((truth, pts, _, _),) = pose_hard.coverage_clouds("box_corner", 0.003, 1, 1000, first=213)
    fld = pose_hard.OBJECTS["box_corner"].field
    fit = LMSolver(fld).solve(pts, se3.invert(truth))
    r, jac = residuals_and_jacobian(fld, fit.object_from_tool, pts)
    length = characteristic_length(fld)
    scale = np.array([1.0] * 3 + [1.0 / length] * 3)
    axes = np.eye(6)
    turned = np.linalg.qr(np.random.default_rng(1).standard_normal((6, 6)))[0]
    measured = []
    for basis in (axes, turned):
        a = jac * scale @ basis
        h = judge.curvature(fld, fit.object_from_tool, pts, basis * scale[:, None], a.T @ a, r)
        measured.append(basis @ h.kept(judge.CURVATURE_FLOOR) @ basis.T)
    np.testing.assert_allclose(
        measured[1], measured[0], rtol=1e-6, atol=1e-9 * np.abs(measured[0]).max()
    )


def test_the_judgement_does_not_depend_on_where_lm_stopped_at_the_minimum() -> None:
    """Cloud 213 of the box's corner at 3 mm, 10k points: LM from the seed and from the
    truth stops at the same minimum (costs 3e-11 of the cost apart, poses 1e-3 degree
    apart); the stated spread along the weak rotation was 0.71 and 1.15 degrees, the
    bias correction 0.2 and 0.7 degree."""
    ((truth, pts, bubble, seed),) = pose_hard.coverage_clouds(
        "box_corner", 0.003, 1, 10000, first=213
    )
    fld = pose_hard.OBJECTS["box_corner"].field
    rays = cloud.camera_rays(pts, bubble)
    judged = []
    for start in (seed, truth):
        fit = LMSolver(fld).solve(pts, se3.invert(start))
        judged.append(judge.uncertainty(fld, fit.object_from_tool, pts, rays_in_tool=rays))
    sd = [np.sqrt(np.linalg.eigvalsh(u.covariance[3:, 3:])[-1]) for u in judged]
    assert sd[1] == pytest.approx(sd[0], rel=0.05), np.degrees(sd)
    moved = np.degrees(np.linalg.norm(judged[0].correction[3:] - judged[1].correction[3:]))
    assert moved < 0.05, moved


def test_the_spread_takes_the_flat_curvature_the_bias_correction_is_kept_from(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The measured curvature is kept at least ``judge.CURVATURE_FLOOR`` of ``J^T J`` for
    the Newton steps that undo the rays' bias (below it, on noisy finite differences,
    they threw some answers tens of degrees off), and at least the lower
    ``judge.SPREAD_CURVATURE_FLOOR`` for the stated spread: cloud 213 of the box's corner
    at 3 mm (10k points), where the cost along the weak rotation is flatter than half of
    ``J^T J``, states a wider spread with the same correction as with the one floor."""
    ((_, pts, bubble, seed),) = pose_hard.coverage_clouds("box_corner", 0.003, 1, 10000, first=213)
    fld = pose_hard.OBJECTS["box_corner"].field
    rays = cloud.camera_rays(pts, bubble)
    fit = LMSolver(fld).solve(pts, se3.invert(seed))
    now = judge.uncertainty(fld, fit.object_from_tool, pts, rays_in_tool=rays)
    monkeypatch.setattr(judge, "SPREAD_CURVATURE_FLOOR", judge.CURVATURE_FLOOR)
    one_floor = judge.uncertainty(fld, fit.object_from_tool, pts, rays_in_tool=rays)
    np.testing.assert_allclose(now.correction, one_floor.correction, rtol=1e-9, atol=1e-12)
    sd = [np.sqrt(np.linalg.eigvalsh(u.covariance[3:, 3:])[-1]) for u in (now, one_floor)]
    assert sd[0] > 1.2 * sd[1], np.degrees(sd)


def test_the_edges_term_counts_only_points_the_noise_carries_across_an_edge() -> None:
    # A 30 mm cylinder's side seen from both jaws, 15 mm short of either rim, 2 mm of
    # noise across the surface: no point's noise reaches a rim, but the points near the
    # patch's ends pushed inward are within 6 residual RMS of a cap, the reach the
    # observability test keeps clear of. On the code before, those points carried the
    # edges' coherent residual too (a 30 mm cylinder at 3 mm: 30% of its points), and
    # cylinders' 95% regions at 3 mm were half again too wide.
    rng = np.random.default_rng(5)
    fld = fields.CappedCylinder(0.03, 0.08)
    n = 2000
    angle = rng.uniform(-0.6, 0.6, n) + np.pi * (np.arange(n) % 2)
    radius = 0.03 + rng.normal(scale=0.002, size=n)
    z = rng.uniform(-0.025, 0.025, n)
    pts = np.stack([radius * np.cos(angle), radius * np.sin(angle), z], axis=1)
    terms = judge.uncertainty(fld, np.eye(4), pts).terms
    assert terms is not None
    np.testing.assert_array_equal(terms.edge, 0.0)
    # Where the noise does reach a rim, the term is there.
    pts[:, 2] += 0.012
    terms = judge.uncertainty(fld, np.eye(4), pts).terms
    assert terms is not None and np.linalg.norm(terms.edge) > 0.0
