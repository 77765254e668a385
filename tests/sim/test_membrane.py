"""Membrane and depth: the rest shape, a known indentation, the plate, the pressure."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sim
from geometry.se3 import invert
from sim.pressure import gauge_pressure_pa
from tests.sim.conftest import held_pose, make_scene

WIDTH_M = 0.11
DELTA_M = 0.008  # how far the flat face presses into the left bubble


def _finger_points(inst: sim.Instant, scene: sim.Scene, side: str = "left") -> np.ndarray:
    """The depth image back-projected into the bubble's plate frame F, (H, W, 3)."""
    renderer = sim.BubbleRenderer(scene, side)
    points = renderer.camera.depth_to_points(inst.images[side].depth_m).astype(np.float64)
    f_from_s = renderer.geometry.finger_from_sensor()
    return points @ f_from_s[:3, :3].T + f_from_s[:3, 3]


def test_undeformed_depth_matches_the_ellipsoid_cap() -> None:
    scene = make_scene()
    far = held_pose(z=1.0)  # the object is a metre away: no contact
    inst = sim.render_grasp("mug", far, WIDTH_M, scene=scene)
    pts = _finger_points(inst, scene)
    ok = np.isfinite(pts[..., 0])
    assert ok.mean() > 0.9
    bubble = scene.gripper_geometry().bubble
    heights = bubble.height_m(pts[ok][:, 1], pts[ok][:, 2])
    np.testing.assert_allclose(pts[ok][:, 0], heights, atol=2e-6)
    assert not inst.frames["left"].arrays["contact"].any()


def _flat_face_scene(divisor: int) -> tuple[sim.Scene, np.ndarray, float]:
    """A 300 mm square bottle whose face is parallel to the left plate, DELTA_M deep."""
    scene = make_scene(
        object={"name": "square_bottle", "dims_m": {"width_m": 0.3, "body_height_m": 0.3}},
        membrane={"resolution_divisor": divisor, "march_steps": 2},
        bubble={"sample_spacing_m": 0.001},
    )
    geom = scene.gripper_geometry()
    face_height = geom.bubble.cap_height_m - DELTA_M
    face_x = geom.plate_x_m(WIDTH_M) - face_height
    # Object y is tool x; the body's centre sits 15 mm below the object's origin (neck).
    pose = held_pose(x=face_x - 0.15, y=0.015, z=0.0)
    return scene, pose, face_height


@pytest.mark.parametrize("divisor,iou_min", [(1, 0.97), (2, 0.94), (4, 0.9)])
def test_flat_indentation_has_the_right_area_and_depth(divisor: int, iou_min: float) -> None:
    scene, pose, face_height = _flat_face_scene(divisor)
    inst = sim.render_grasp(
        "square_bottle",
        pose,
        WIDTH_M,
        scene=scene,
        dims_m={"width_m": 0.3, "body_height_m": 0.3},
    )
    arrays = inst.frames["left"].arrays
    renderer = sim.BubbleRenderer(scene, "left")
    rest_f = renderer._o_f + renderer.rest_range[..., None] * renderer.dirs_f
    expected = rest_f[..., 0] > face_height
    contact = arrays["contact"]
    iou = (contact & expected).sum() / (contact | expected).sum()
    assert iou > iou_min
    # Where the membrane touches the face it lies on the face (away from the rim).
    pts = _finger_points(inst, scene)
    interior = expected & (rest_f[..., 0] > face_height + 0.002)
    np.testing.assert_allclose(pts[interior][:, 0], face_height, atol=2e-4)
    # Nowhere does the membrane pass through the face.
    assert np.nanmax(pts[..., 0]) < face_height + 2e-4
    # The indentation along the plate normal peaks at the imposed depth.
    assert np.nanmax(rest_f[..., 0] - pts[..., 0]) == pytest.approx(DELTA_M, abs=3e-4)


def test_flat_indentation_volume_and_area_match_the_cap_formulas() -> None:
    scene, pose, face_height = _flat_face_scene(2)
    world = sim.World(scene)
    state = world.contact("left", WIDTH_M, pose)
    b = scene.gripper_geometry().bubble
    an, at, al, c = (
        b.semi_axis_normal_m,
        b.semi_axis_lateral_m,
        b.semi_axis_length_m,
        b.center_offset_m,
    )
    area = math.pi * at * al * (1 - ((face_height + c) / an) ** 2)
    volume = math.pi * at * al * DELTA_M**2 * (3 * an - DELTA_M) / (3 * an**2)
    assert state.in_contact
    assert state.contact_area_m2 == pytest.approx(area, rel=0.03)
    assert state.displaced_volume_m3 == pytest.approx(volume, rel=0.05)


def test_membrane_bottoms_out_on_the_plate() -> None:
    scene = make_scene(membrane={"resolution_divisor": 1})
    inst = sim.render_grasp("mug", held_pose(x=0.0), 0.0, scene=scene)  # jaws shut on a mug
    pts = _finger_points(inst, scene)
    assert np.nanmin(pts[..., 0]) > -1e-6
    assert np.isfinite(inst.images["left"].depth_m).any()


def test_pressure_rises_monotonically_with_squeeze() -> None:
    scene = make_scene(effects=["membrane", "depth", "pressure"])
    pressures = []
    for width in np.linspace(0.10, 0.045, 8):
        inst = sim.render_grasp(
            "mug", held_pose(), float(width), scene=scene, effects=scene.effects
        )
        pressures.append((inst.pressures["left"].pressure_pa, inst.pressures["right"].pressure_pa))
    left = [p[0] for p in pressures]
    assert left[0] == pytest.approx(scene.bubble.inflation_pa)  # not yet touching
    assert all(b > a for a, b in zip(left[1:], left[2:], strict=False))
    assert np.all(np.diff(left) >= 0)


def test_ideal_gas_isothermal() -> None:
    v0, p_inf, amb = 1e-4, 1000.0, 101_325.0
    for dv in (0.0, 1e-5, 3e-5):
        gauge = gauge_pressure_pa(
            dv, rest_volume_m3=v0, inflation_pa=p_inf, ambient_pa=amb, compliance_m3_per_pa=0.0
        )
        assert (gauge + amb) * (v0 - dv) == pytest.approx((p_inf + amb) * v0, rel=1e-12)
    # With compliance the free membrane gives back volume: p (V0 - dV + C dp) = p0 V0.
    c = 5e-9
    gauge = gauge_pressure_pa(
        2e-5, rest_volume_m3=v0, inflation_pa=p_inf, ambient_pa=amb, compliance_m3_per_pa=c
    )
    p, p0 = gauge + amb, p_inf + amb
    assert p * (v0 - 2e-5 + c * (p - p0)) == pytest.approx(p0 * v0, rel=1e-9)
    assert (
        p_inf
        < gauge
        < gauge_pressure_pa(
            2e-5, rest_volume_m3=v0, inflation_pa=p_inf, ambient_pa=amb, compliance_m3_per_pa=0.0
        )
    )


def test_object_pose_frame_is_consistent_with_depth() -> None:
    # A contact point's depth back-projected into the tool frame lies on the object.
    scene = make_scene(membrane={"resolution_divisor": 1})
    pose = held_pose()
    inst = sim.render_grasp("mug", pose, 0.07, scene=scene)
    for side in ("left", "right"):
        renderer = sim.BubbleRenderer(scene, side)
        pts = renderer.camera.depth_to_points(inst.images[side].depth_m).astype(np.float64)
        contact = inst.frames[side].arrays["contact"] & np.isfinite(pts[..., 0])
        interior = contact & (inst.frames[side].arrays["indentation_m"] > 0.002)
        tool_pts = (
            pts[interior] @ renderer.tool_from_sensor(0.07)[:3, :3].T
            + renderer.tool_from_sensor(0.07)[:3, 3]
        )
        obj_pts = tool_pts @ invert(pose)[:3, :3].T + invert(pose)[:3, 3]
        phi = scene.object_model().field.value(obj_pts)
        assert interior.sum() > 500
        assert np.percentile(np.abs(phi), 95) < 3e-4
