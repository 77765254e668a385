"""A scene on the MuJoCo world: the jaws close on force, the truth it reports."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim import load_scene
from sim.mujoco.model import ShellSpec
from sim.mujoco.world import MujocoWorld


def test_a_force_grasp_of_the_mug_and_the_engines_truth() -> None:
    scene = load_scene("scenes/mug_handover.yaml")
    scene = dataclasses.replace(scene, duration_secs=0.9)
    world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=0.012))
    while not world.done:
        snap = world.step()
    assert snap.gripper_state == "holding"
    assert all(snap.in_contact.values())
    # The WSG model stopped at the commanded 12 N of the engine's grip force.
    assert snap.force_n == pytest.approx(12.0, rel=0.15)
    left, right = snap.wrench["left"], snap.wrench["right"]
    assert left.force_n[0] > 5.0 and right.force_n[0] < -5.0
    assert 5e-4 < left.area_m2 < 8e-3 and 0.0 <= left.slipping_fraction <= 1.0
    assert 1500.0 < snap.pressure_pa["left"] < 10000.0
    msg = world.wrench_truth(7)
    assert msg.source == "mujoco" and msg.header.stamp_nanos == 7
    assert np.allclose(msg.object_force_n, -msg.bubble_force_n.sum(axis=0), atol=1e-9)
    assert all(v > 5e-5 for v in msg.volume_m3)
    assert snap.membranes_f is not None and snap.membrane_spacing_m == 0.012
    assert all(np.all(np.isfinite(m)) for m in snap.membranes_f.values())


def test_scenes_with_a_support_are_refused() -> None:
    scene = load_scene("scenes/stack_on_table.yaml")
    with pytest.raises(ValueError, match="support"):
        MujocoWorld(scene)
