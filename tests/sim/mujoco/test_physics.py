"""The MuJoCo bubbles: the mesh, inflation, the gas law under squeeze, the contact wrench.

A coarse mesh (8 mm edges, 169 vertices a bubble) keeps this to seconds on one core; the
module's squeeze is run once and shared.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geometry import objects
from geometry.gripper import BubbleGeometry, GripperGeometry
from geometry.se3 import make_pose
from sim.mujoco.mesh import cap_mesh, enclosed_volume_m3, membrane_mesh, triangle_normals
from sim.mujoco.model import OBJECT_MASS_KG, ShellSpec
from sim.mujoco.physics import GraspPhysics
from sim.scene import rotation_from_rpy_deg

SPACING_M = 0.008
# The mug's axis along tool y, its handle along tool z (the scenes' mount), centred.
MUG_POSE = make_pose(rotation_from_rpy_deg((0.0, -90.0, -90.0)), np.array([0.0, 0.0, 0.005]))


def test_cap_mesh_encloses_the_cap_volume_and_faces_out() -> None:
    bubble = BubbleGeometry()
    mesh = cap_mesh(bubble, 0.004)
    assert enclosed_volume_m3(mesh.rest_m, mesh.triangles) == pytest.approx(
        bubble.volume_m3(), rel=0.02
    )
    assert np.all(triangle_normals(mesh.rest_m, mesh.triangles)[:, 0] > 0)
    assert np.all(mesh.rest_m[mesh.pinned, 0] == 0.0)
    assert mesh.rest_m[:, 0].max() == pytest.approx(bubble.cap_height_m)
    with pytest.raises(ValueError, match="spacing_m"):
        cap_mesh(bubble, 0.0)


@pytest.fixture(scope="module")
def squeeze() -> dict[str, object]:
    """A free mug squeezed between the bubbles, then gravity switched on."""
    ph = GraspPhysics(
        gripper=GripperGeometry(),
        object_model=objects.make("mug"),
        width_m=0.11,
        tool_from_object=MUG_POSE,
        shell=ShellSpec(mesh_spacing_m=SPACING_M),
        hand=False,
    )
    ph.inflate(0.3)
    record: dict[str, object] = {
        "inflated_pa": ph.pressure_pa.copy(),
        "apex_m": ph.mid_surface_f("left")[:, 0].max(),
    }
    pressures = []
    width = 0.11
    for _ in range(320):  # close at 160 mm/s to a 62 mm opening
        width = max(0.062, width - 0.16 * ph.timestep_secs)
        ph.set_width(width)
        ph.step()
        pressures.append((ph.width_m(), float(ph.pressure_pa.mean())))
    for _ in range(50):
        ph.step()
    record["squeezed_pa"] = ph.pressure_pa.copy()
    record["pressures"] = pressures
    ph.model.opt.gravity[:] = (0.0, 0.0, -9.81)
    for _ in range(300):
        ph.step()
    z0 = ph.tool_from_object()[2, 3]
    for _ in range(100):
        ph.step()
    record["creep_m_per_s"] = abs(ph.tool_from_object()[2, 3] - z0) / (100 * ph.timestep_secs)
    record["contacts"] = ph.contacts()
    record["physics"] = ph
    return record


def test_inflates_to_about_a_kilopascal_and_the_rest_shape(squeeze: dict) -> None:
    assert np.allclose(squeeze["inflated_pa"], 1000.0, atol=20.0)
    # The stress-free reference is lower; the air stretches it to about the rest cap.
    assert squeeze["apex_m"] == pytest.approx(BubbleGeometry().cap_height_m, abs=0.0015)


def test_pressure_rises_as_the_bubbles_are_squeezed(squeeze: dict) -> None:
    pressures = np.array(squeeze["pressures"])
    at = {w: pressures[np.argmin(np.abs(pressures[:, 0] - w)), 1] for w in (0.09, 0.075, 0.062)}
    assert at[0.09] < at[0.075] < at[0.062]
    # About 15 mm into each bubble: several kilopascals (the feasibility study: 2.8 kPa
    # at 9 mm), far from a blow-up.
    assert 2500.0 < squeeze["squeezed_pa"].mean() < 12000.0
    assert abs(squeeze["squeezed_pa"][0] - squeeze["squeezed_pa"][1]) < 50.0


def test_contact_wrench_on_a_free_object_balances_gravity(squeeze: dict) -> None:
    c = squeeze["contacts"]
    weight = OBJECT_MASS_KG["mug"] * 9.81
    assert c.object_force_n == pytest.approx([0.0, 0.0, weight], abs=0.03 * weight)
    # What the object gets from the bubbles, the bubbles get back.
    assert np.allclose(c.bubble_force_n.sum(axis=0), -c.object_force_n, atol=1e-9)
    # The squeeze: each bubble pushed outwards along tool x, about equally.
    left, right = c.bubble_force_n[:, 0]
    assert left > 5.0 and right < -5.0
    assert abs(left + right) < 0.05 * left
    assert c.count[0] > 10 and c.count[1] > 10
    assert squeeze["creep_m_per_s"] < 0.002


def test_the_membrane_does_not_sink_into_the_object(squeeze: dict) -> None:
    # Latex does not sink into a mug: the contact surface the cameras see (the shell's
    # vertices offset by the flex radius) lies on the object, not inside it. MuJoCo's
    # soft contact, averaged with the object geoms' default softness, let it sink about
    # 0.9 mm under a few kilopascals.
    ph = squeeze["physics"]
    depth = np.asarray(ph.data.contact.dist[: ph.data.ncon])
    assert len(depth) > 20
    assert np.median(depth) > -1e-4 and depth.min() > -3e-4
    field = objects.make("mug").field
    object_from_tool = np.linalg.inv(ph.tool_from_object())
    for side in ("left", "right"):
        pose = ph.tool_from_finger(side)
        points = ph.surface_f(side) @ pose[:3, :3].T + pose[:3, 3]
        value = field.value(points @ object_from_tool[:3, :3].T + object_from_tool[:3, 3])
        touching = value < 0.001
        assert touching.sum() > 10
        assert np.median(value[touching]) > -1e-4


def test_every_quantity_is_finite(squeeze: dict) -> None:
    ph = squeeze["physics"]
    c = squeeze["contacts"]
    for arr in (c.bubble_force_n, c.bubble_torque_nm, c.object_force_n, c.object_torque_nm):
        assert np.all(np.isfinite(arr))
    for side in ("left", "right"):
        assert np.all(np.isfinite(ph.surface_f(side)))
    assert np.all(np.isfinite(ph.volume_m3)) and np.all(ph.volume_m3 > 0)
    assert math.isfinite(ph.width_m())


def test_reference_mesh_is_lower_than_the_rest_cap() -> None:
    bubble = BubbleGeometry()
    mesh = membrane_mesh(bubble, SPACING_M)
    assert mesh.rest_m[:, 0].max() < bubble.cap_height_m
