"""Lowering a held object onto a support (sim.support): push, shear, placed or dropped."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import sim
from sim.scene import SceneError, scene_from_dict
from sim.support import SupportSpec
from sim.world import World

EFFECTS = ("membrane", "pressure", "gripper", "shear", "ground_truth")


def run(release_at_secs: float, **support: float) -> tuple[World, list]:
    scene = sim.load_scene("scenes/stack_on_table.yaml").with_effects(EFFECTS)
    spec = dataclasses.replace(scene.support, **support)
    world = World(dataclasses.replace(scene, support=spec, duration_secs=release_at_secs + 0.5))
    snaps = []
    while not world.done:
        snap = world.step()
        snaps.append(snap)
        if snap.frame_index == 3:
            world.command("grasp", width_m=0.05, speed_m_per_s=0.1, force_n=12.0)
        if abs(snap.time_secs - release_at_secs) < 1e-6:
            world.command("release", width_m=0.11, speed_m_per_s=0.1, force_n=0.0)
    return world, snaps


def test_the_support_pushes_the_object_up_and_the_membranes_shear() -> None:
    # 12 mm under the base, lowered at 10 mm/s from 1.8 s: touch at 3.0 s.
    world, snaps = run(3.5)
    at = {round(s.time_secs, 3): s for s in snaps}
    assert at[2.9].tool_from_object[1, 3] == pytest.approx(0.0, abs=1e-9)
    assert at[3.3].tool_from_object[1, 3] == pytest.approx(0.003, abs=1e-4)  # pushed up
    assert at[3.3].shear_in_tool_m["left"][0] == pytest.approx(0.003, abs=5e-4)
    placement = world.placement
    assert placement is not None and placement.placed and placement.gap_m == 0.0
    assert placement.touch_secs == pytest.approx(3.0, abs=0.04)
    assert placement.push_m == pytest.approx(0.01 * (3.5 + 1 / 30 - placement.touch_secs))
    assert placement.tilt_deg == pytest.approx(0.0, abs=1e-6)


def test_a_release_in_the_air_drops_the_object_by_the_gap() -> None:
    world, snaps = run(2.5)  # 7 mm lowered of 12
    placement = world.placement
    assert placement is not None and not placement.placed and placement.touch_secs is None
    # Commands apply from the next frame: the arm stops one frame after 2.5 s.
    gap = 0.012 - 0.01 * (2.5 + 1 / 30 - 1.8)
    assert placement.gap_m == pytest.approx(gap, abs=1e-9)
    assert snaps[-1].tool_from_object[1, 3] == pytest.approx(-gap, abs=1e-9)  # it fell


def test_support_is_checked() -> None:
    with pytest.raises(ValueError, match="down_in_tool"):
        SupportSpec(down_in_tool=(0.0, 0.0, 2.0))
    with pytest.raises(SceneError, match="support"):
        scene_from_dict({"object": "mug", "support": {"speed_m_per_s": -1}}, path="s.yaml")
    assert np.isfinite(sim.load_scene("scenes/stack_on_mug.yaml").support.clearance_m)
