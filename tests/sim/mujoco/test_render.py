"""Ray casting a membrane mesh: the rest cap's range, material points riding the latex."""

from __future__ import annotations

import numpy as np
import pytest

from sim.mujoco.mesh import cap_mesh
from sim.mujoco.render import MeshView
from sim.scene import ObjectSpec, Scene


@pytest.fixture(scope="module")
def view_and_rest() -> tuple[MeshView, np.ndarray, object]:
    scene = Scene(name="t", object=ObjectSpec(name="mug"))
    geometry = scene.gripper_geometry()
    camera = scene.camera.intrinsics()
    f_from_s = geometry.finger_from_sensor()
    unit = camera.unit_rays()
    rest = geometry.bubble.intersect_rays(f_from_s[:3, 3], unit @ f_from_s[:3, :3].T)
    mesh = cap_mesh(geometry.bubble, 0.003)
    view = MeshView(
        mesh,
        unit,
        fx_px=camera.fx_px,
        fy_px=camera.fy_px,
        cx_px=camera.cx_px,
        cy_px=camera.cy_px,
        finger_from_sensor=f_from_s,
        rest_range_m=rest,
    )
    return view, rest, mesh


def test_the_rest_mesh_casts_the_rest_caps_range(view_and_rest: tuple) -> None:
    view, rest, mesh = view_and_rest
    out = view.render(mesh.rest_m, np.zeros(len(mesh.rest_m), bool))
    both = np.isfinite(out["range_m"]) & np.isfinite(rest)
    # Every pixel on the cap but a thin rim band (the mesh's chords) sees the mesh...
    assert both.sum() > 0.97 * np.isfinite(rest).sum()
    # ...at the ellipsoid's range, within the chords' sag (3 mm edges).
    assert np.nanmax(np.abs(out["range_m"] - rest)[both]) < 0.0005
    assert np.median(np.abs(out["range_m"] - rest)[both]) < 0.0001
    assert not out["contact"].any()
    assert np.allclose(out["material_shift_m"][both], 0.0, atol=2e-4)
    assert np.all((out["cos_incidence"][both] > 0) & (out["cos_incidence"][both] <= 1.0001))


def test_material_points_move_with_the_latex_and_contact_follows_the_vertices(
    view_and_rest: tuple,
) -> None:
    view, rest, mesh = view_and_rest
    moved = mesh.rest_m.copy()
    # Slide the latex 2 mm along F z near the apex, where the cap is nearly flat: its
    # material (and the dots printed on it) goes with it.
    near_apex = np.hypot(moved[:, 1], moved[:, 2]) < 0.015
    moved[near_apex, 2] += 0.002
    touching = np.hypot(moved[:, 1], moved[:, 2] - 0.002) < 0.008
    out = view.render(moved, touching)
    centre = out["contact"]
    assert centre.sum() > 100
    shift = out["material_shift_m"][centre]
    assert np.median(shift[:, 1]) == pytest.approx(0.002, abs=0.0002)
    assert np.median(np.abs(shift[:, 0])) < 0.0002
