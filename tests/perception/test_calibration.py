"""The calibration's computations: pressure zero, free-bubble statistics, the mount solve."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from geometry.camera import PinholeCamera
from geometry.gripper import SIDES, GripperGeometry
from geometry.se3 import invert, log_so3, make_pose, rotation_about
from perception.calibration.mount import Grasp, solve_mounts
from perception.calibration.procedure import (
    contact_points,
    free_points,
    pressure_zero,
    reference_stats,
)
from sim import render_grasp
from sim.emulated_lab import AWAY, CALIBRATION_POSES, CALIBRATION_SCENE
from sim.emulated_rig import AsBuiltCamera, as_built_renderer
from sim.scene import load_scene

CAD = GripperGeometry().finger_from_sensor()


def test_pressure_zero_is_the_mean_with_its_standard_error() -> None:
    rng = np.random.default_rng(0)
    readings = 41.0 + 0.8 * rng.standard_normal(400)
    zero, sigma, noise = pressure_zero(readings, resolution_pa=0.526)
    assert zero == pytest.approx(41.0, abs=3 * sigma)
    assert noise == pytest.approx(0.8, rel=0.1)
    assert sigma == pytest.approx(np.hypot(noise / 20, 0.526 / np.sqrt(12 * 400)))
    with pytest.raises(ValueError, match="at least 2"):
        pressure_zero([1.0], resolution_pa=0.5)


def test_reference_stats_count_invalid_pixels_and_the_noise() -> None:
    rng = np.random.default_rng(1)
    frames = [0.08 + 0.001 * rng.standard_normal((10, 10)).astype(np.float32) for _ in range(20)]
    for f in frames:
        f[0, :] = np.nan  # a row never valid: 10 %
    frames[0][5, 5] = np.nan  # one pixel invalid once: still valid
    mean, stats = reference_stats(frames)
    assert stats["invalid_fraction"] == pytest.approx(0.1) and stats["frames"] == 20
    assert stats["noise_m"] == pytest.approx(0.001, rel=0.2)
    assert np.isnan(mean[0]).all() and np.isfinite(mean[1:]).all()


def test_contact_points_are_the_pixels_pushed_in() -> None:
    camera = PinholeCamera.from_fov(20, 10)
    free = np.full(camera.shape, 0.08, np.float32)
    pressed = free.copy()
    pressed[2:5, 3:8] = 0.07
    pressed[6, 6] = 0.079  # within the threshold: not contact
    rng = np.random.default_rng(0)
    pts = contact_points(pressed, free, camera, min_indent_m=0.003, n=1000, rng=rng)
    assert pts.shape == (15, 3) and np.allclose(pts[:, 2], 0.07)
    assert free_points(free, camera, 50, rng).shape == (50, 3)


def _mount_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = invert(a) @ b
    return float(np.degrees(np.linalg.norm(log_so3(d[:3, :3])))), float(
        np.linalg.norm(d[:3, 3]) * 1e3
    )


def test_the_mounts_of_an_as_built_rig_are_recovered_from_rendered_grasps() -> None:
    """Each camera 2 degrees and 2 mm off its CAD mount, seen through the simulator: the
    solve finds both mounts within 0.3 degrees and 0.3 mm, and says how sure it is."""
    scene = load_scene(CALIBRATION_SCENE)
    off = {
        "left": make_pose(rotation_about(np.array([1.0, -1.0, 1.0]) / 3**0.5, np.radians(2.0)), [0.0012, 0.0012, -0.0011]),
        "right": make_pose(rotation_about(np.array([-1.0, 1.0, 0.5]) / 1.5, np.radians(2.0)), [-0.0007, 0.0013, 0.0013]),
    }  # fmt: skip
    renderers = {s: as_built_renderer(scene, s, AsBuiltCamera(s, off[s])) for s in SIDES}
    rng = np.random.default_rng(0)

    def depths(pose: np.ndarray, width: float, n: int) -> dict[str, list[np.ndarray]]:
        snap = render_grasp("cylinder", pose, width, effects=scene.effects, scene=scene).snapshot
        return {
            s: [
                r.render(dataclasses.replace(snap, frame_index=k)).arrays["depth_m"]
                for k in range(n)
            ]
            for s, r in renderers.items()
        }

    free = {s: reference_stats(d)[0] for s, d in depths(AWAY, 0.11, 6).items()}
    grasps = []
    for (pose, _), width in zip(CALIBRATION_POSES[:4], (0.047, 0.045, 0.041, 0.051), strict=True):
        seen = depths(pose, width, 2)
        points = {
            s: contact_points(
                reference_stats(seen[s])[0],
                free[s],
                renderers[s].camera,
                min_indent_m=0.003,
                n=400,
                rng=rng,
            )
            for s in SIDES
        }
        grasps.append(Grasp(width, points))
    free_pts = {s: free_points(free[s], renderers[s].camera, 1000, rng) for s in SIDES}
    solution = solve_mounts(free_pts, grasps, 0.03)
    for side in SIDES:
        fit = solution.mounts[side]
        deg, mm = _mount_error(CAD @ off[side], fit.finger_from_sensor)
        assert deg < 0.3 and mm < 0.3, (side, deg, mm)
        assert fit.correction_deg == pytest.approx(2.0, abs=0.3)
        assert 0 < fit.rotation_sigma_deg < 0.3 and 0 < fit.translation_sigma_mm < 0.3
    assert np.isfinite(solution.grasp_rms_mm) and solution.grasp_rms_mm < 1.0
    with pytest.raises(ValueError, match="2 grasp\\(s\\) with contact on both bubbles; at least 3"):
        solve_mounts(free_pts, grasps[:2], 0.03)
