"""The world: speed-limited, force-controlled jaws; contact anchors; the scene clock."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from tests.sim.conftest import make_scene

GRASP = [
    {"t_secs": 0.0, "command": "grasp", "width_m": 0.07, "speed_m_per_s": 0.05, "force_n": 12.0}
]


def _run(scene: sim.Scene) -> list[sim.WorldSnapshot]:
    world = sim.World(scene)
    snaps = []
    while not world.done:
        snaps.append(world.step())
    return snaps


def test_grasp_takes_time_at_the_speed_limit_and_reaches_the_force() -> None:
    scene = make_scene(
        effects=["membrane", "depth", "gripper"],
        duration_secs=1.6,
        gripper={"initial_width_m": 0.11, "commands": GRASP},
    )
    snaps = _run(scene)
    widths = np.array([s.width_m for s in snaps])
    dt = scene.frame_period_secs
    assert np.all(np.abs(np.diff(widths)) <= 0.05 * dt + 1e-12)
    moving = [s for s in snaps if s.gripper_state == "moving"]
    assert len(moving) > 10
    assert max(s.speed_m_per_s for s in moving) == pytest.approx(0.05, rel=1e-6)
    final = snaps[-1]
    assert final.gripper_state == "holding"
    assert final.force_n == pytest.approx(12.0, rel=0.02)
    assert final.speed_m_per_s == 0.0
    assert all(final.in_contact.values())
    # Pressure (gauge) rose above inflation in both bubbles.
    assert min(final.pressure_pa.values()) > scene.bubble.inflation_pa


def test_release_opens_and_contact_ends() -> None:
    commands = GRASP + [
        {"t_secs": 1.2, "command": "release", "width_m": 0.11, "speed_m_per_s": 0.1}
    ]
    scene = make_scene(
        effects=["membrane", "depth", "gripper", "ground_truth"],
        duration_secs=2.0,
        gripper={"commands": commands},
    )
    snaps = _run(scene)
    assert snaps[-1].width_m == pytest.approx(0.11)
    assert not any(snaps[-1].in_contact.values())
    assert snaps[-1].anchors == {"left": None, "right": None}
    held = [s for s in snaps if s.gripper_state == "holding"]
    assert held and all(s.anchors["left"] is not None for s in held)


def test_without_the_gripper_effect_commands_jump() -> None:
    scene = make_scene(
        effects=["membrane", "depth"],
        gripper={"commands": [{"t_secs": 0.1, "command": "grasp", "width_m": 0.065}]},
    )
    snaps = _run(scene)
    first_after = next(s for s in snaps if s.time_secs >= 0.1 - 1e-9)
    assert first_after.width_m == 0.065
    assert all(s.speed_m_per_s == 0.0 for s in snaps)


def test_grasp_with_nothing_between_the_fingers_faults() -> None:
    scene = make_scene(
        effects=["gripper"],
        duration_secs=2.6,
        trajectory=[{"t_secs": 0.0, "xyz_m": [0.0, 0.0, 1.0]}],
        gripper={
            "commands": [{"t_secs": 0.0, "command": "grasp", "speed_m_per_s": 0.1, "force_n": 5.0}]
        },
    )
    assert _run(scene)[-1].gripper_state == "fault"


def test_external_command_moves_the_jaws() -> None:
    scene = make_scene(effects=["gripper"], duration_secs=1.0)
    world = sim.World(scene)
    world.step()
    world.command("move", width_m=0.09, speed_m_per_s=0.1, force_n=20.0)
    for _ in range(10):
        snap = world.step()
    assert snap.width_m == pytest.approx(0.09)
    with pytest.raises(ValueError, match="unknown gripper command"):
        world.command("wave", width_m=0.0, speed_m_per_s=0.1, force_n=1.0)


def test_run_to_and_frame_count() -> None:
    scene = make_scene(duration_secs=0.5)
    assert scene.frame_count == 16
    world = sim.World(scene)
    snap = world.run_to(0.2)
    assert snap.frame_index == 6 and snap.time_secs == pytest.approx(0.2)
    with pytest.raises(ValueError):
        world.run_to(0.0)
    assert world.run_to(10.0).frame_index == 15 and world.done


def test_a_taut_membrane_stops_the_jaws_wider_with_a_broader_dent() -> None:
    """``bubble.tension_n_per_m``: the tension pulls on the object along a tent around
    the patch, so at the same force the jaws stop wider, the object sits shallower, and
    the membrane around the patch is dented (the patch itself no larger)."""
    scenes = [
        make_scene(
            effects=["membrane", "depth", "gripper", "pressure"],
            duration_secs=1.6,
            gripper={"initial_width_m": 0.11, "commands": GRASP},
            bubble={"tension_n_per_m": tension},
        )
        for tension in (0.0, 60.0)
    ]
    finals = [_run(scene)[-1] for scene in scenes]
    for final in finals:
        assert final.gripper_state == "holding"
        assert final.force_n == pytest.approx(12.0, rel=0.02)
    slack, taut = finals
    assert taut.width_m > slack.width_m + 0.003
    assert max(taut.pressure_pa.values()) < max(slack.pressure_pa.values())
    frames = [
        sim.BubbleRenderer(scene, "left").render(final).arrays
        for scene, final in zip(scenes, finals, strict=True)
    ]
    for arrays in frames:
        assert np.all(np.isfinite(arrays["indentation_m"]))
    # dented by more than 1 mm outside the object's patch: the tent
    tent = [int(((a["indentation_m"] > 1e-3) & ~a["contact"]).sum()) for a in frames]
    patch = [int(a["contact"].sum()) for a in frames]
    assert tent[0] < 0.02 * patch[0]
    assert tent[1] > 0.1 * patch[1]
    assert patch[1] <= patch[0]
    assert frames[1]["indentation_m"].max() < frames[0]["indentation_m"].max()


def test_tension_is_checked() -> None:
    with pytest.raises(Exception, match="tension_n_per_m"):
        make_scene(bubble={"tension_n_per_m": -1.0})
