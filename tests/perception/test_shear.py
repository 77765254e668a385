"""Shear from the dot pattern against known membrane motion (perception/shear.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.shear import DotPlane, angle_error_deg
from geometry.camera import PinholeCamera
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
)

CAMERA = PinholeCamera.from_fov()


@pytest.fixture(scope="module")
def scene() -> DotPlane:
    return DotPlane(CAMERA, seed=3)


@pytest.fixture(scope="module")
def reference(scene: DotPlane) -> tuple[np.ndarray, np.ndarray]:
    return scene.render()


def tracker_for(
    reference: tuple[np.ndarray, np.ndarray], params: ShearParams | None = None
) -> ShearTracker:
    tracker = ShearTracker(params or ShearParams())
    tracker.set_reference(reference[0], reference[1], CAMERA)
    return tracker


def assert_finite(result) -> None:
    for value in (result.shear_px, result.sum_px, result.direction, result.shear_mm):
        assert np.isfinite(value).all()
    assert math.isfinite(result.magnitude_px) and math.isfinite(result.torsion_rad)


@pytest.mark.parametrize(
    "params",
    [
        ShearParams(),
        ShearParams(scale=0.5, farneback=FarnebackParams(levels=2)),
        ShearParams(method="dis", dis=DisParams(preset="medium")),
    ],
    ids=["farneback", "farneback-half", "dis-medium"],
)
def test_translations_in_eight_directions(scene, reference, params):
    tracker = tracker_for(reference, params)
    errors = []
    for k in range(8):
        angle = k * math.pi / 4
        t = (2.0 * math.cos(angle), 2.0 * math.sin(angle))
        result = tracker.update(*scene.render(t))
        assert result.direction_defined
        assert_finite(result)
        errors.append(angle_error_deg(result.direction, np.array(t)))
        # Reported in full-resolution pixels whatever the working scale.
        assert result.magnitude_px == pytest.approx(2.0, abs=0.1)
        # Face-on plane: mm = px * depth / fx.
        np.testing.assert_allclose(result.shear_mm, np.array(t) * scene.mm_per_px(), atol=0.05)
        assert abs(result.torsion_rad) < math.radians(0.3)
    assert max(errors) < 3.0
    assert float(np.median(errors)) < 1.5


def test_twist_gives_torsion_and_no_direction(scene, reference):
    tracker = tracker_for(reference)
    for deg in (-3.0, 1.5, 3.0):
        result = tracker.update(*scene.render((0.0, 0.0), math.radians(deg)))
        assert_finite(result)
        # A twist about the middle of the membrane has no net tangential shear.
        assert not result.direction_defined
        assert math.degrees(result.torsion_rad) == pytest.approx(deg, abs=0.3)


def test_twist_without_depth_is_measured_in_the_image(scene, reference):
    tracker = ShearTracker(ShearParams())
    tracker.set_reference(reference[0])
    result = tracker.update(scene.render((0.0, 0.0), math.radians(2.0))[0])
    assert math.degrees(result.torsion_rad) == pytest.approx(2.0, abs=0.3)
    assert np.all(result.shear_mm == 0.0)


def test_mixture_of_translation_and_twist(scene, reference):
    tracker = tracker_for(reference)
    t = (1.5 * math.cos(2.2), 1.5 * math.sin(2.2))
    result = tracker.update(*scene.render(t, math.radians(2.0)))
    assert result.direction_defined
    assert angle_error_deg(result.direction, np.array(t)) < 3.0
    assert math.degrees(result.torsion_rad) == pytest.approx(2.0, abs=0.3)


def test_zero_shear_is_undefined_not_nan(scene, reference):
    tracker = tracker_for(reference)
    for frame in (reference, scene.render()):  # the same image, and fresh noise
        result = tracker.update(*frame)
        assert not result.direction_defined
        assert np.all(result.direction == 0.0)
        assert result.magnitude_px < 0.05
        assert_finite(result)


def test_nan_depth_pixels_are_masked(scene, reference):
    ir, depth = scene.render((1.0, -1.0))
    depth = depth.copy()
    depth[40:90, 60:120] = np.nan
    depth[::7, :] = np.nan
    ref_depth = reference[1].copy()
    ref_depth[100:140, 10:50] = np.nan
    tracker = ShearTracker(ShearParams())
    tracker.set_reference(reference[0], ref_depth, CAMERA)
    result = tracker.update(ir, depth, keep_fields=True)
    assert_finite(result)
    assert result.valid_fraction < 0.8
    assert not result.mask[60, 80] and not result.mask[120, 30]
    assert angle_error_deg(result.direction, np.array([1.0, -1.0])) < 3.0


def test_all_nan_depth_and_saturated_ir_give_finite_zero(scene, reference):
    tracker = tracker_for(reference)
    ir, depth = scene.render((1.0, 0.0))
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


def test_partly_saturated_ir_keeps_the_direction(scene, reference):
    tracker = tracker_for(reference)
    ir, depth = scene.render((0.0, 2.0))
    ir = ir.copy()
    ir[30:80, 30:100] = 65535
    result = tracker.update(ir, depth)
    assert_finite(result)
    assert angle_error_deg(result.direction, np.array([0.0, 2.0])) < 3.0


def test_reference_drop_and_reset(scene, reference):
    tracker = tracker_for(reference)
    shifted = scene.render((2.0, 0.0))
    assert tracker.update(*shifted).direction_defined
    tracker.drop_reference()
    result = tracker.update(*shifted)
    assert not result.has_reference and not result.direction_defined
    assert_finite(result)
    tracker.set_reference(shifted[0], shifted[1], CAMERA)
    assert tracker.update(*shifted).magnitude_px < 0.05
    back = tracker.update(*reference)
    assert angle_error_deg(back.direction, np.array([-1.0, 0.0])) < 3.0


def test_warm_start_tracks_a_ramp(scene, reference):
    tracker = tracker_for(
        reference, ShearParams(warm_start=True, farneback=FarnebackParams(levels=1))
    )
    for step in range(1, 9):
        result = tracker.update(*scene.render((0.0, -0.5 * step)))
    # One pyramid level alone cannot jump 4 px; warm starts get there frame by frame.
    assert result.magnitude_px == pytest.approx(4.0, abs=0.2)
    assert angle_error_deg(result.direction, np.array([0.0, -1.0])) < 2.0


def test_shape_mismatch_is_an_error(reference):
    tracker = tracker_for(reference)
    with pytest.raises(ValueError, match="shape"):
        tracker.update(reference[0][:-2])


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
        ShearParams(**kwargs)


def test_flow_params_name_the_bad_field():
    with pytest.raises(ValueError, match="poly_n"):
        FarnebackParams(poly_n=4)
    with pytest.raises(ValueError, match="preset"):
        DisParams(preset="slow")
    with pytest.raises(ValueError, match="patch_stride"):
        DisParams(patch_size=4, patch_stride=8)


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
    s1, s2, d1, d2 = geometry.tangential_displacement_mm(flow, indices, depth)
    assert s1.shape[0] == indices.shape[0]
    np.testing.assert_allclose(d1, 1.0, atol=0.02)
    np.testing.assert_allclose(d2, 0.5, atol=0.02)


def test_tangent_basis_falls_back_on_degenerate_points():
    np.testing.assert_array_equal(tangent_basis(np.zeros((2, 3))), np.eye(3))
    line = np.stack([np.linspace(0, 1, 10), np.zeros(10), np.ones(10)], axis=1)
    np.testing.assert_array_equal(tangent_basis(line), np.eye(3))
