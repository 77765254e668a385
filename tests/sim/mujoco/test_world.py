"""A scene on the MuJoCo world: the jaws close on force, the truth it reports."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim import load_scene
from sim.mujoco.model import ShellSpec
from sim.mujoco.world import DROPPED_M, MujocoWorld


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


def test_a_free_mug_being_filled_slips_out_of_a_light_grip() -> None:
    """``slip``: the hand lets go once the jaws hold; the engine's gravity on the object
    (its mass the load's, growing) against MuJoCo's friction: still, then the edge
    slips, then the whole patch, and the mug falls out."""
    scene = load_scene("scenes/mug_fill.yaml")
    load = dataclasses.replace(scene.load, fill_kg_per_s=1.0, fill_from_secs=0.9)
    scene = dataclasses.replace(scene, duration_secs=2.4, load=load)
    world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=0.012))
    snaps, shares, masses, dropped = [], [], [], []
    while not world.done:
        snaps.append(world.step())
        shares.append(max(world.truth.contacts.slipping_fraction))
        masses.append(world.physics.object_mass_kg())
        dropped.append(world.dropped)
    t = np.array([s.time_secs for s in snaps])
    slide = np.array([np.hypot(*s.slide_m) for s in snaps])
    held = [i for i, s in enumerate(snaps) if s.load_n.any()]
    assert held and t[held[0]] < 0.8  # let go once the jaws hold
    # Before the filling: held still (the weight on the membrane's give, no creep).
    still = (t > t[held[0]] + 0.15) & (t < 0.9)
    assert np.ptp(slide[still]) < 0.2e-3
    assert snaps[held[0]].load_n[1] == pytest.approx(-0.35 * 9.81, rel=1e-6)
    assert masses[-1] == pytest.approx(load.max_mass_kg, rel=1e-6)  # filled to the brim
    # The edge slips before the whole patch, and the mug leaves the grip. (While the
    # jaws close, the rim's first contacts sit at their cone: not counted.)
    after = np.array(shares[held[0] :])
    edge, patch = int(np.argmax(after >= 0.5)), int(np.argmax(after >= 0.9))
    assert 0 < edge <= patch and t[held[0] + edge] > 0.9
    assert np.all(np.isfinite(slide))
    # Fallen out, it is parked: it stays where it left the grip (no floor here).
    gone = dropped.index(True)
    assert slide[gone] > DROPPED_M and gone < len(snaps) - 1
    assert np.ptp(slide[gone + 1 :]) < 1e-6
