"""Tests of the pinhole ToF camera model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geometry.camera import PinholeCamera


def test_from_fov_matches_field_of_view() -> None:
    cam = PinholeCamera.from_fov(224, 172, hfov_deg=62.0, vfov_deg=45.0)
    # The outer edge of the outer pixel column lies at half the field of view.
    edge = (cam.width_px - 0.5 - cam.cx_px) / cam.fx_px
    assert math.degrees(math.atan(edge)) == pytest.approx(31.0)
    edge_v = (cam.height_px - 0.5 - cam.cy_px) / cam.fy_px
    assert math.degrees(math.atan(edge_v)) == pytest.approx(22.5)
    assert cam.shape == (172, 224)


def test_depth_to_points_round_trip_and_nan() -> None:
    cam = PinholeCamera.from_fov(40, 30)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.04, 0.11, cam.shape).astype(np.float32)
    depth[3, 4] = np.nan
    depth[5, 6] = 0.0
    points = cam.depth_to_points(depth)
    assert points.shape == (30, 40, 3)
    assert points.dtype == np.float32
    assert np.all(np.isnan(points[3, 4])) and np.all(np.isnan(points[5, 6]))
    valid = np.isfinite(points[..., 2])
    np.testing.assert_allclose(points[..., 2][valid], depth[valid], rtol=1e-6)
    uv = cam.project(points[valid].astype(np.float64))
    rows, cols = np.nonzero(valid)
    np.testing.assert_allclose(uv[:, 0], cols, atol=1e-3)
    np.testing.assert_allclose(uv[:, 1], rows, atol=1e-3)


def test_project_behind_camera_is_nan() -> None:
    cam = PinholeCamera.from_fov(40, 30)
    uv = cam.project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert np.all(np.isnan(uv[:2]))
    np.testing.assert_allclose(uv[2], [cam.cx_px, cam.cy_px])


def test_unit_rays_and_range_to_depth() -> None:
    cam = PinholeCamera.from_fov(40, 30)
    unit = cam.unit_rays()
    np.testing.assert_allclose(np.linalg.norm(unit, axis=-1), 1.0)
    depth = cam.range_to_depth(np.full(cam.shape, 0.1))
    points = cam.depth_to_points(depth)
    np.testing.assert_allclose(np.linalg.norm(points, axis=-1), 0.1, rtol=1e-6)


def test_solid_angle_sums_to_fov() -> None:
    cam = PinholeCamera.from_fov(224, 172, hfov_deg=62.0, vfov_deg=45.0)
    a, b = math.tan(math.radians(31.0)), math.tan(math.radians(22.5))
    # Solid angle of a rectangular pyramid with half-widths a, b at unit distance.
    exact = 4.0 * math.asin(a * b / math.sqrt((1 + a * a) * (1 + b * b)))
    assert cam.pixel_solid_angle_sr().sum() == pytest.approx(exact, rel=1e-3)


@pytest.mark.parametrize("field,value", [("width_px", 0), ("fx_px", -1.0), ("cx_px", float("nan"))])
def test_bad_intrinsics_name_the_field(field: str, value: float) -> None:
    kwargs = dict(width_px=4, height_px=3, fx_px=2.0, fy_px=2.0, cx_px=1.5, cy_px=1.0)
    kwargs[field] = value
    with pytest.raises(ValueError, match=field):
        PinholeCamera(**kwargs)


def test_wrong_depth_shape_raises() -> None:
    with pytest.raises(ValueError, match="shape"):
        PinholeCamera.from_fov(40, 30).depth_to_points(np.zeros((3, 3)))


def test_from_frame_reads_the_message_intrinsics_and_size() -> None:
    from types import SimpleNamespace

    depth = np.zeros((172, 224), np.float32)
    frame = SimpleNamespace(
        depth_m=depth,
        ir=np.zeros((172, 224), np.uint16),
        fx_px=190.0,
        fy_px=200.0,
        cx_px=111.5,
        cy_px=85.5,
    )
    cam = PinholeCamera.from_frame(frame)
    assert (cam.width_px, cam.height_px, cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px) == (
        224,
        172,
        190.0,
        200.0,
        111.5,
        85.5,
    )
    frame.depth_m = np.zeros((0, 0), np.float32)  # a scene without the depth effect
    assert PinholeCamera.from_frame(frame).width_px == 224
