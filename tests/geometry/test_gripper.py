"""Tests of the gripper and bubble geometry (frames, membrane cap, camera mounts)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geometry.camera import PinholeCamera
from geometry.gripper import DEFAULT_GRIPPER, BubbleGeometry, GripperGeometry, tool_from_sensor


@pytest.mark.parametrize("side", ["left", "right"])
def test_tool_from_sensor_is_rigid(side: str) -> None:
    pose = tool_from_sensor(side, 0.08)
    rot = pose[:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])


def test_cameras_mirror_each_other_and_look_inward() -> None:
    width = 0.07
    left = tool_from_sensor("left", width)
    right = tool_from_sensor("right", width)
    # The left camera is behind the left plate (x > plate x) and looks to -x, +z.
    plate_x = DEFAULT_GRIPPER.plate_x_m(width)
    assert left[0, 3] > plate_x and right[0, 3] < -plate_x
    assert left[0, 2] < 0 and right[0, 2] > 0
    assert left[2, 2] > 0 and right[2, 2] > 0  # tilted towards the finger tip
    # A 180 degree turn about tool z maps one camera onto the other.
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(flip @ right, left, atol=1e-12)


def test_opening_moves_plates_symmetrically() -> None:
    a = tool_from_sensor("left", 0.05)
    b = tool_from_sensor("left", 0.09)
    np.testing.assert_allclose(b[:3, 3] - a[:3, 3], [0.02, 0, 0], atol=1e-12)
    np.testing.assert_allclose(b[:3, :3], a[:3, :3])


def test_membrane_apex_and_footprint() -> None:
    bubble = BubbleGeometry()
    assert bubble.height_m(0.0, 0.0) == pytest.approx(bubble.cap_height_m)
    fy, fz = bubble.footprint_semi_axes_m()
    assert bubble.height_m(fy, 0.0) == pytest.approx(0.0, abs=1e-9)
    assert bubble.height_m(0.0, fz) == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(bubble.height_m(fy * 1.01, 0.0))


def test_surface_samples_integrate_the_cap_volume() -> None:
    bubble = BubbleGeometry()
    samples = bubble.surface_samples(0.001)
    # Volume = integral of height over the footprint; the samples' plate projection
    # (area * |n_x|) is the footprint cell.
    volume = np.sum(samples.points_f[:, 0] * samples.area_m2 * samples.normals_f[:, 0])
    assert volume == pytest.approx(bubble.volume_m3(), rel=1e-2)
    np.testing.assert_allclose(np.linalg.norm(samples.normals_f, axis=1), 1.0)


def test_camera_ray_hits_rest_membrane_at_analytic_height() -> None:
    geom = GripperGeometry()
    cam = PinholeCamera.from_fov(224, 172)
    f_from_s = geom.finger_from_sensor()
    dirs = cam.unit_rays() @ f_from_s[:3, :3].T
    t = geom.bubble.intersect_rays(f_from_s[:3, 3], dirs)
    hit_fraction = np.isfinite(t).mean()
    assert hit_fraction > 0.5
    points = f_from_s[:3, 3] + t[..., None] * dirs
    ok = np.isfinite(t)
    heights = geom.bubble.height_m(points[ok][:, 1], points[ok][:, 2])
    np.testing.assert_allclose(points[ok][:, 0], heights, atol=1e-9)
    # The centre pixel sees the membrane within the sensor's 4-11 cm working range.
    centre = t[cam.height_px // 2, cam.width_px // 2]
    assert 0.04 <= centre <= 0.11


def test_bad_geometry_names_the_field() -> None:
    with pytest.raises(ValueError, match="cap_height_m"):
        BubbleGeometry(cap_height_m=0.1)
    with pytest.raises(ValueError, match="camera_pitch_deg"):
        GripperGeometry(camera_pitch_deg=120.0)
    with pytest.raises(ValueError, match="side"):
        tool_from_sensor("middle", 0.05)


def test_camera_pitch_rotates_optical_axis() -> None:
    pose = GripperGeometry(camera_pitch_deg=30.0).finger_from_sensor()
    axis = pose[:3, 2]
    assert math.degrees(math.atan2(axis[2], axis[0])) == pytest.approx(30.0)
