"""Shear: the printed dots move with the membrane by the imposed tangential motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import sim
from tests.sim.conftest import held_pose, make_scene

EFFECTS = ["membrane", "depth", "ir", "dot_pattern", "shear", "ground_truth"]


def _render(pose: np.ndarray, anchor: np.ndarray | None) -> sim.Instant:
    scene = make_scene(effects=EFFECTS, membrane={"resolution_divisor": 1})
    return sim.render_grasp(
        "mug", pose, 0.065, scene=scene, effects=EFFECTS, anchor_tool_from_object=anchor
    )


@pytest.mark.parametrize("shift_m", [0.002, 0.004])
def test_dots_move_by_the_imposed_displacement(shift_m: float) -> None:
    # Slide the mug along its own axis (tool y): the contact geometry is unchanged, so
    # the depth stays and only the membrane material (and its dots) moves.
    anchor = held_pose()
    moved = held_pose(y=shift_m)
    ref = _render(anchor, anchor)
    cur = _render(moved, anchor)
    a_ref, a_cur = ref.frames["left"].arrays, cur.frames["left"].arrays
    np.testing.assert_allclose(a_ref["range_m"], a_cur["range_m"], atol=1e-6, equal_nan=True)
    interior = cv2.erode(a_cur["contact"].astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    # Material shift in the left plate frame: F y is tool -y.
    np.testing.assert_allclose(a_cur["material_shift_m"][interior][:, 0], -shift_m, atol=1e-5)
    np.testing.assert_allclose(a_cur["material_shift_m"][interior][:, 1], 0.0, atol=1e-5)
    # In the image the dots moved by the projection of that displacement.
    rows, cols = np.nonzero(interior)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    win = cv2.createHanningWindow((c1 - c0, r1 - r0), cv2.CV_32F)
    (du, dv), response = cv2.phaseCorrelate(
        a_ref["albedo"][r0:r1, c0:c1].astype(np.float32),
        a_cur["albedo"][r0:r1, c0:c1].astype(np.float32),
        win,
    )
    renderer = sim.BubbleRenderer(make_scene(), "left")
    p = renderer.rest_range[rows, cols, None] * renderer.unit[rows, cols]
    p = a_cur["range_m"][rows, cols, None] * renderer.unit[rows, cols]
    delta_sensor = renderer.tool_from_sensor(0.065)[:3, :3].T @ np.array([0.0, shift_m, 0.0])
    uv = renderer.camera.project(p)
    uv_moved = renderer.camera.project(p + delta_sensor)
    expected = np.median(uv_moved - uv, axis=0)
    assert np.hypot(*expected) > 2.0  # a visible motion, in pixels
    np.testing.assert_allclose([du, dv], expected, atol=0.6)
    # Ground truth reports the same shift, tool (y, z) in metres.
    gt = cur.ground_truth
    assert gt is not None
    np.testing.assert_allclose(gt.shear_left_m, [shift_m, 0.0], atol=0.05e-3)


def test_shear_saturates_at_the_stick_limit_and_zero_without_anchor() -> None:
    anchor = held_pose()
    far = _render(held_pose(y=0.03), anchor)
    limit = make_scene().bubble.max_shear_m
    shift = far.frames["left"].arrays["material_shift_m"]
    assert np.nanmax(np.hypot(shift[..., 0], shift[..., 1])) == pytest.approx(limit, rel=1e-5)
    assert np.linalg.norm(far.ground_truth.shear_left_m) == pytest.approx(limit, rel=1e-3)
    none = _render(held_pose(y=0.03), None)
    assert not none.frames["left"].arrays["material_shift_m"].any()
    assert not none.ground_truth.shear_left_m.any()


def test_twist_gives_opposite_shear_across_the_patch() -> None:
    anchor = held_pose()
    twisted = make_scene(
        trajectory=[{"t_secs": 0.0, "xyz_m": [0.0, 0.0, 0.005], "rpy_deg": [4, 0, 0]}]
    ).tool_from_object(0.0)
    arrays = _render(twisted, anchor).frames["left"].arrays
    shift = arrays["material_shift_m"]
    renderer = sim.BubbleRenderer(make_scene(), "left")
    z_f = renderer._o_f[2] + arrays["range_m"] * renderer.dirs_f[..., 2]
    contact = arrays["contact"]
    # A twist about the grasp axis moves material along F y one way above the axis and
    # the other way below it.
    above = shift[contact & (z_f > 0.02), 0]
    below = shift[contact & (z_f < -0.005), 0]
    assert np.median(above) * np.median(below) < 0
