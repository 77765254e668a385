"""The ``wrench`` and ``slip`` effects: true contact wrenches, and slip under a load."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import sim
from sim.friction import LoadSpec, PullKeyframe, stiffening
from sim.scene import SceneError
from tests.sim.conftest import make_scene

WORLD = ("pressure", "gripper", "wrench", "slip")


def run(scene: sim.Scene) -> list[sim.WorldSnapshot]:
    world = sim.World(scene)
    snaps = []
    while not world.done:
        snaps.append(world.step())
    return snaps


def fill_scene(force_n: float = 6.0, **load: object) -> sim.Scene:
    scene = sim.load_scene("scenes/mug_fill.yaml")
    cmd = dataclasses.replace(scene.gripper.commands[0], force_n=force_n)
    spec = dataclasses.replace(scene.load, **load) if load else scene.load
    return dataclasses.replace(
        scene,
        effects=WORLD,
        gripper=dataclasses.replace(scene.gripper, commands=(cmd,)),
        load=spec,
    )


def test_held_still_the_wrench_balances_the_weight_and_the_grip() -> None:
    snaps = run(dataclasses.replace(fill_scene(), load=LoadSpec(mass_kg=0.35)))
    last = snaps[-1]
    truth = sim.wrench_truth(last, 0)
    # Each bubble presses with the grip force, along the closing axis, opposite ways.
    assert truth.bubble_force_n[0, 0] == pytest.approx(last.force_n, rel=1e-6)
    assert truth.bubble_force_n[1, 0] == pytest.approx(-last.force_n, rel=1e-6)
    # The bubbles carry the weight: the contact force on the object cancels the load.
    np.testing.assert_allclose(truth.object_force_n + last.load_n, 0.0, atol=0.02)
    assert truth.source == "sim" and np.isfinite(truth.bubble_torque_nm).all()
    assert all(w.slipping_fraction == 0.0 for w in last.wrench.values())
    assert 0 < -last.slide_m[0] < 0.003  # the elastic sag, under the stick limit


def test_filling_slips_the_edge_first_then_the_patch_and_a_firm_grip_holds() -> None:
    light = run(fill_scene(6.0))
    fractions = [s.wrench["left"].slipping_fraction for s in light if "left" in s.wrench]
    partial = [f for f in fractions if 0.0 < f < 1.0]
    assert partial, "the patch's edge slips before the whole patch"
    first_partial = fractions.index(partial[0])
    assert 1.0 in fractions[first_partial:]
    assert light[-1].slide_m[0] < -0.05  # slid out of the hand
    firm = run(fill_scene(20.0))
    assert firm[-1].slide_m[0] > -0.006  # held: only the elastic sag
    assert max(s.wrench["left"].slipping_fraction for s in firm if s.wrench) < 1.0


def test_a_pull_past_the_stick_limit_slides_the_object_out() -> None:
    scene = dataclasses.replace(sim.load_scene("scenes/mug_pull.yaml"), effects=WORLD)
    snaps = run(scene)
    before = [s for s in snaps if s.time_secs < 1.2]
    assert abs(before[-1].slide_m[1]) < 1e-6
    assert snaps[-1].slide_m[1] > 0.01  # along the pull, tool +z


def test_without_slip_the_object_follows_its_script_and_without_wrench_no_wrench() -> None:
    snaps = run(dataclasses.replace(fill_scene(), effects=("pressure", "gripper", "wrench")))
    assert all(np.all(s.slide_m == 0) for s in snaps)
    assert any(s.wrench for s in snaps)
    plain = run(dataclasses.replace(fill_scene(), effects=("pressure", "gripper")))
    assert not any(s.wrench for s in plain)


def test_simulator_reports_wrench_truth_only_when_listed() -> None:
    scene = make_scene(effects=["membrane", "depth", "wrench"], duration_secs=0.1)
    assert sim.Simulator(scene).step().wrench is not None
    assert sim.Simulator(make_scene(duration_secs=0.1)).step().wrench is None


def test_stiffening_is_one_at_the_deepest_point_and_finite_for_no_patch() -> None:
    g = stiffening(np.array([0.0, 0.002, 0.004]), 1.0)
    np.testing.assert_allclose(g, [2.0, 1.5, 1.0])
    assert stiffening(np.zeros(3), 1.0).tolist() == [1.0, 1.0, 1.0]


def test_bad_load_is_refused_naming_the_field() -> None:
    with pytest.raises(SceneError, match="gravity_in_tool"):
        make_scene(load={"gravity_in_tool": [0, -2, 0]})
    with pytest.raises(SceneError, match="pull"):
        make_scene(load={"pull": [{"t_secs": 1.0}, {"t_secs": 0.5}]})
    assert LoadSpec(pull=(PullKeyframe(t_secs=0.0), PullKeyframe(t_secs=1.0, force_n=(0, 0, 2))))
