"""Shear from the dot pattern against the simulator's ground truth (perception/shear/).

The frames come from ``sim`` (a mug held in ``scenes/mug_grasp.yaml`` and moved in the
hand, with the ``shear`` and ``dot_pattern`` effects); the truth follows the material
(``sim.material_flow.truth``). Shifts are given in mm here for readability. Analytic checks of the pieces are at the end.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.shear import angle_error_deg, scored_mask
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from perception.shear import (
    DisParams,
    FarnebackParams,
    MembraneGeometry,
    ShearParams,
    ShearTracker,
    flow_curl,
    rotation_about_centroid,
    stretch_ir,
    tangent_basis,
    tool_basis,
)
from runtime.params import build_params
from sim.material_flow import SimGrasp, truth


@cache
def grasp() -> SimGrasp:
    return SimGrasp()


@cache
def instant(shift_mm: tuple[float, float] = (0.0, 0.0), twist_deg: float = 0.0, index: int = 0):
    shift_m = (shift_mm[0] / 1000.0, shift_mm[1] / 1000.0)
    return grasp().instant(shift_m, math.radians(twist_deg), index)


@cache
def expected(shift_mm: tuple[float, float], twist_deg: float, index: int, sensor: str):
    """``(truth_px, truth_mm, torsion_rad)`` of a moved frame against the rest frame."""
    g, ref = grasp(), instant()
    mask = scored_mask(ref.images[sensor])
    px, metres, torsion = truth(
        g.geometry, g.camera, ref, instant(shift_mm, twist_deg, index), sensor, mask
    )
    return px, metres * 1000.0, torsion


def basis_of(sensor: str) -> np.ndarray:
    return tool_basis(instant().images[sensor].tool_from_sensor)


def tracker_for(sensor: str, params: ShearParams | None = None) -> ShearTracker:
    tracker = ShearTracker(params or ShearParams())
    ref = instant().images[sensor]
    tracker.set_reference(ref.ir, ref.depth_m, PinholeCamera.from_frame(ref), basis_of(sensor))
    return tracker


def frame(shift_mm=(0.0, 0.0), twist_deg=0.0, index=1, sensor="left"):
    image = instant(tuple(shift_mm), twist_deg, index).images[sensor]
    return image.ir, image.depth_m


def assert_finite(result) -> None:
    for value in (result.shear_px, result.sum_px, result.direction, result.shear_m):
        assert np.isfinite(value).all()
    assert math.isfinite(result.magnitude_px) and math.isfinite(result.torsion_rad)


EIGHT = [
    (round(math.cos(k * math.pi / 4), 6), round(math.sin(k * math.pi / 4), 6)) for k in range(8)
]


@pytest.mark.parametrize(
    "params",
    [
        ShearParams(),
        ShearParams(scale=0.5),
        ShearParams(method="dis", dis=DisParams(preset="fast")),
    ],
    ids=["farneback", "farneback-half", "dis-fast"],
)
@pytest.mark.parametrize("sensor", SIDES)
def test_translations_in_eight_directions(params, sensor):
    tracker = tracker_for(sensor, params)
    px_errors, mm_errors = [], []
    for k, shift in enumerate(EIGHT):
        result = tracker.update(*frame(shift, 0.0, 10 + k, sensor))
        truth_px, truth_mm, _ = expected(shift, 0.0, 10 + k, sensor)
        assert result.direction_defined and result.metric_defined
        assert_finite(result)
        # The paper's sum over the working image's masked pixels, in full-resolution px.
        pixels = result.valid_fraction * (172 * 224) * params.scale**2
        np.testing.assert_allclose(result.sum_px, result.shear_px * pixels, rtol=0.02)
        px_errors.append(angle_error_deg(result.direction, truth_px))
        mm_errors.append(angle_error_deg(result.shear_m, truth_mm))
        # Reported in full-resolution pixels whatever the working scale.
        # Flow smooths the sharp edge of the moving patch: a few percent short.
        assert result.magnitude_px == pytest.approx(np.hypot(*truth_px), rel=0.15)
        # Further short in mm: the camera sees the membrane's far side foreshortened
        # (more mm per px, smaller dots), where the flow falls shortest.
        assert np.hypot(*result.shear_m) * 1000.0 == pytest.approx(np.hypot(*truth_mm), rel=0.25)
    assert max(px_errors) < 3.0
    assert float(np.median(mm_errors)) < 3.0 and max(mm_errors) < 6.0


@pytest.mark.parametrize("sensor", SIDES)
def test_twist_gives_the_torsion(sensor):
    tracker = tracker_for(sensor)
    for twist in (-4.0, 4.0):
        result = tracker.update(*frame((0.0, 0.0), twist, 20, sensor))
        _, _, torsion = expected((0.0, 0.0), twist, 20, sensor)
        assert_finite(result)
        assert math.copysign(1.0, result.torsion_rad) == math.copysign(1.0, twist)
        # The membrane outside the contact does not turn: the truth is the same fit.
        assert math.degrees(result.torsion_rad) == pytest.approx(math.degrees(torsion), abs=0.3)


@pytest.mark.parametrize("sensor", SIDES)
def test_twist_without_depth_is_measured_in_the_image(sensor):
    tracker = ShearTracker(ShearParams())
    tracker.set_reference(instant().images[sensor].ir)
    result = tracker.update(frame((0.0, 0.0), 4.0, 20, sensor)[0])
    assert not result.metric_defined and np.all(result.shear_m == 0.0)
    # In the image the rotation is about the optical axis: the left camera looks along
    # tool -x, so a twist about tool +x turns its image the other way.
    facing = math.copysign(1.0, basis_of(sensor)[2, 2])
    assert facing * result.torsion_rad > math.radians(0.5)


@pytest.mark.parametrize("sensor", SIDES)
def test_mixture_of_translation_and_twist(sensor):
    tracker = tracker_for(sensor)
    shift = (-1.2, 0.8)
    result = tracker.update(*frame(shift, 3.0, 30, sensor))
    truth_px, truth_mm, torsion = expected(shift, 3.0, 30, sensor)
    assert angle_error_deg(result.direction, truth_px) < 3.0
    assert angle_error_deg(result.shear_m, truth_mm) < 5.0
    # With a concurrent translation the flow smooths the moving patch's sharp edge more,
    # and the fitted rotation comes out short (bench/shear.py measures by how much).
    assert result.torsion_rad == pytest.approx(torsion, rel=0.4)


def test_zero_shear_is_undefined_not_nan():
    tracker = tracker_for("left")
    for ir, depth in (frame(index=0), frame(index=1), frame(index=2)):  # same image, new noise
        result = tracker.update(ir, depth)
        assert result.has_reference and not result.direction_defined
        assert np.all(result.direction == 0.0)
        assert result.magnitude_px < 0.05
        assert np.hypot(*result.shear_m) < 0.05e-3
        assert_finite(result)


def test_nan_depth_pixels_are_masked():
    ir, depth = frame((1.0, 0.0), 0.0, 40)
    depth = depth.copy()
    depth[40:90, 60:120] = np.nan
    depth[::7, :] = np.nan
    tracker = tracker_for("left")
    result = tracker.update(ir, depth, keep_fields=True)
    assert_finite(result)
    assert result.valid_fraction < 0.7
    assert not result.mask[60, 80] and not result.mask[14, 100]
    truth_px, truth_mm, _ = expected((1.0, 0.0), 0.0, 40, "left")
    assert angle_error_deg(result.direction, truth_px) < 3.0
    assert angle_error_deg(result.shear_m, truth_mm) < 5.0


def test_nan_in_the_reference_and_all_invalid_frames_give_finite_zero():
    ir_ref, depth_ref = frame(index=0)
    tracker = ShearTracker(ShearParams())
    tracker.set_reference(
        ir_ref, np.full_like(depth_ref, np.nan), PinholeCamera.from_frame(instant().images["left"])
    )
    assert_finite(tracker.update(*frame((1.0, 0.0), 0.0, 40)))
    tracker = tracker_for("left")
    ir, depth = frame((1.0, 0.0), 0.0, 40)
    for bad_ir, bad_depth in (
        (ir, np.full_like(depth, np.nan)),
        (np.full_like(ir, 65535), depth),
        (np.zeros_like(ir), depth),
    ):
        result = tracker.update(bad_ir, bad_depth)
        assert result.has_reference
        assert_finite(result)
        assert not result.direction_defined
        assert result.valid_fraction == 0.0


def test_partly_saturated_ir_keeps_the_direction():
    tracker = tracker_for("left")
    ir, depth = frame((0.0, 1.0), 0.0, 41)
    ir = ir.copy()
    ir[30:80, 30:100] = 65535
    result = tracker.update(ir, depth)
    assert_finite(result)
    truth_px, _, _ = expected((0.0, 1.0), 0.0, 41, "left")
    assert angle_error_deg(result.direction, truth_px) < 3.0


def test_reference_drop_and_reset():
    tracker = tracker_for("left")
    shifted = frame((1.0, 0.0), 0.0, 40)
    assert tracker.update(*shifted).direction_defined
    tracker.drop_reference()
    result = tracker.update(*shifted)
    assert not result.has_reference and not result.direction_defined
    assert_finite(result)
    tracker.set_reference(*shifted)
    assert tracker.update(*shifted).magnitude_px < 0.05
    back = tracker.update(*frame(index=3))
    truth_px, _, _ = expected((1.0, 0.0), 0.0, 40, "left")
    assert angle_error_deg(back.direction, -truth_px) < 5.0


def test_track_gives_the_field_that_update_summarises():
    tracker = tracker_for("left", ShearParams(scale=0.5))
    shifted = frame((1.0, 0.0), 0.0, 40)
    flow, mask, work_depth = tracker.track(*shifted)
    assert flow.shape == (*mask.shape, 2) and work_depth is not None
    assert work_depth.shape == mask.shape and mask.any()
    result = tracker.update(*shifted, keep_fields=True)
    assert result.flow is not None and result.mask is not None
    np.testing.assert_array_equal(result.mask, mask)
    np.testing.assert_allclose(result.flow, flow)
    tracker.drop_reference()
    with pytest.raises(ValueError, match="no reference"):
        tracker.track(*shifted)


def test_warm_start_tracks_a_ramp_a_single_level_cannot_jump():
    params = {"levels": 1, "winsize": 9}
    cold = tracker_for("left", ShearParams(farneback=FarnebackParams(**params)))
    warm = tracker_for("left", ShearParams(warm_start=True, farneback=FarnebackParams(**params)))
    for step in range(1, 9):
        ir_depth = frame((0.5 * step, 0.0), 0.0, 50 + step)
        result_cold = cold.update(*ir_depth)
        result_warm = warm.update(*ir_depth)
    truth_px, truth_mm, _ = expected((4.0, 0.0), 0.0, 58, "left")
    assert result_cold.magnitude_px < 0.3 * np.hypot(*truth_px)
    assert result_warm.magnitude_px == pytest.approx(np.hypot(*truth_px), rel=0.2)
    assert angle_error_deg(result_warm.direction, truth_px) < 2.0


def test_shape_mismatch_is_an_error():
    tracker = tracker_for("left")
    with pytest.raises(ValueError, match="shape"):
        tracker.update(frame()[0][:-2])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"method": "lucas"}, "method"),
        ({"scale": 0.0}, "scale"),
        ({"max_depth_m": 0.01}, "max_depth_m"),
        ({"min_magnitude_px": -1.0}, "min_magnitude_px"),
    ],
)
def test_params_name_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        build_params(ShearParams, kwargs)


def test_flow_params_name_the_bad_field():
    with pytest.raises(ValueError, match="poly_n"):
        build_params(FarnebackParams, {"poly_n": 4})
    with pytest.raises(ValueError, match="preset"):
        build_params(DisParams, {"preset": "slow"})
    with pytest.raises(ValueError, match="patch_stride"):
        build_params(DisParams, {"patch_size": 4, "patch_stride": 8})


def test_stretch_ir_flat_and_empty_images_are_mid_grey():
    flat = np.full((10, 12), 65535, np.uint16)
    assert np.all(stretch_ir(flat) == 128)
    ir = np.arange(120, dtype=np.uint16).reshape(10, 12)
    assert np.all(stretch_ir(ir, np.zeros_like(ir, bool)) == 128)
    out = stretch_ir(ir, ir > 10)
    assert out.dtype == np.uint8 and np.all(out[ir <= 10] == 128)


@settings(max_examples=40, deadline=None)
@given(
    theta=st.floats(-1.2, 1.2),
    tx=st.floats(-5, 5),
    ty=st.floats(-5, 5),
    seed=st.integers(0, 1000),
)
def test_rotation_about_centroid_recovers_rigid_motion(theta, tx, ty, seed):
    points = np.random.default_rng(seed).uniform(-10, 10, (50, 2))
    c, s = math.cos(theta), math.sin(theta)
    moved = points @ np.array([[c, s], [-s, c]]) + np.array([tx, ty])
    d = moved - points
    angle, ok = rotation_about_centroid(points[:, 0], points[:, 1], d[:, 0], d[:, 1])
    assert ok and angle == pytest.approx(theta, abs=1e-9)


def test_rotation_about_centroid_degenerate_is_undefined():
    one = np.ones(5)
    assert rotation_about_centroid(one, one, one, one) == (0.0, False)
    assert rotation_about_centroid(one[:2], one[:2], one[:2], one[:2]) == (0.0, False)


def test_flow_curl_of_a_rotation_is_twice_its_sine():
    ys, xs = np.mgrid[0:40, 0:50].astype(np.float64)
    theta = 0.05
    rx, ry = xs - 25, ys - 20
    flow = np.stack(
        [
            math.cos(theta) * rx - math.sin(theta) * ry - rx,
            math.sin(theta) * rx + math.cos(theta) * ry - ry,
        ],
        axis=-1,
    ).astype(np.float32)
    mask = np.ones((40, 50), bool)
    mask[:, :5] = False
    curl = flow_curl(flow, mask)
    assert np.isnan(curl[:, :6]).all()
    np.testing.assert_allclose(curl[1:-1, 6:-1], 2 * math.sin(theta), atol=1e-5)


def test_tangential_displacement_on_a_tilted_plane():
    """A plane at 30 deg about y, each dot moved by 1 mm along t1: the geometry recovers it."""
    camera = PinholeCamera.from_fov(64, 48)
    tilt = math.radians(30.0)
    normal = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    z0 = 0.08
    rays = camera.rays()
    # The plane n . p = n . (0, 0, z0) met by each pixel's ray r (z = 1): depth = n.p / n.r.
    depth = (z0 * math.cos(tilt) / (rays @ normal)).astype(np.float32)
    mask = np.ones(depth.shape, bool)
    geometry = MembraneGeometry.from_depth(depth, mask, camera)
    np.testing.assert_allclose(geometry.basis[2], normal, atol=1e-6)
    np.testing.assert_allclose(geometry.basis @ geometry.basis.T, np.eye(3), atol=1e-12)
    points = camera.depth_to_points(depth).astype(np.float64)
    move_m = 0.001 * geometry.basis[0] + 0.0005 * geometry.basis[1]
    pixels = camera.project(points + move_m)
    grid = np.stack(np.meshgrid(np.arange(64), np.arange(48)), axis=-1)
    flow = (pixels - grid).astype(np.float32)
    keep = np.zeros(depth.shape, bool)
    keep[5:-5, 5:-5] = True
    indices = np.flatnonzero(keep)
    s1, s2, d1, d2 = geometry.tangential_displacement_m(flow, indices, depth)
    assert s1.shape[0] == indices.shape[0]
    np.testing.assert_allclose(d1, 1.0e-3, atol=0.02e-3)
    np.testing.assert_allclose(d2, 0.5e-3, atol=0.02e-3)


def test_tangent_basis_falls_back_on_degenerate_points():
    np.testing.assert_array_equal(tangent_basis(np.zeros((2, 3))), np.eye(3))
    line = np.stack([np.linspace(0, 1, 10), np.zeros(10), np.ones(10)], axis=1)
    np.testing.assert_array_equal(tangent_basis(line), np.eye(3))
