"""Object variants reach MuJoCo: the model's object geoms span the variant's own bounds."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from geometry import variants
from geometry.gripper import GripperGeometry
from sim.mujoco.mesh import membrane_mesh
from sim.mujoco.model import ShellSpec, grasp_mjcf


@pytest.mark.parametrize("name", sorted(variants.FAMILIES))
def test_a_variant_becomes_mujoco_geometry_of_its_own_size(name: str) -> None:
    gripper = GripperGeometry()
    mesh = membrane_mesh(gripper.bubble, 0.02)
    for variant in (7, 1011):
        model = variants.make_variant(name, variant)
        xml = grasp_mjcf(
            gripper=gripper,
            mesh=mesh,
            shell=ShellSpec(mesh_spacing_m=0.02),
            object_field=model.field,
            width_m=0.11,
            tool_from_object=np.eye(4),
        )
        mj = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(mj)
        mujoco.mj_forward(mj, data)
        body = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, "object")
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for g in np.flatnonzero(mj.geom_bodyid == body):
            centre, half = mj.geom_aabb[g, :3], mj.geom_aabb[g, 3:]
            rot = data.geom_xmat[g].reshape(3, 3)
            mid = data.geom_xpos[g] + rot @ centre
            reach = np.abs(rot) @ half
            lo, hi = np.minimum(lo, mid - reach), np.maximum(hi, mid + reach)
        want_lo, want_hi = model.bounds_m()
        np.testing.assert_allclose(lo, want_lo, atol=1e-3)
        np.testing.assert_allclose(hi, want_hi, atol=1e-3)
