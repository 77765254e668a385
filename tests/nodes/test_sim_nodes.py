"""The simulator's nodes with the fake IO: one world clock, sensors that share its stamp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from messages.base import Header
from messages.sim import WorldState
from messages.types import GripperCommand
from nodes.bubble_camera import SimBubbleCamera
from nodes.gripper import SimGripper
from nodes.pressure import SimPressure
from nodes.world import WorldNode
from runtime.testing import feed, make_node

START = 1_700_000_000_000_000_000


def _scene_file(tmp_path: Path, **fields: object) -> str:
    data = {
        "name": "node_test",
        "seed": 5,
        "duration_secs": 0.3,
        "object": {"name": "mug"},
        "mount_rpy_deg": [0, -90, -90],
        "trajectory": [{"t_secs": 0.0, "xyz_m": [0.0, 0.0, 0.005]}],
        "effects": ["membrane", "depth", "ir", "pressure", "gripper", "ground_truth"],
        "gripper": {"initial_width_m": 0.07},
    }
    data.update(fields)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _run_world(scene: str, **params: object) -> tuple[WorldNode, object]:
    world, io = make_node(WorldNode, {"scene": scene, **params}, name="world", now_nanos=START)
    io.advance(2.0)
    return world, io


def test_world_publishes_every_frame_then_stops(tmp_path: Path) -> None:
    world, io = _run_world(_scene_file(tmp_path))
    states = io.published["state"]
    assert len(states) == 10  # 0.3 s at 30 Hz: frames 0..9
    assert [s.frame_index for s in states] == list(range(10))
    assert states[0].header.stamp_nanos == pytest.approx(
        START + world.scene.frame_period_secs * 1e9, abs=1
    )
    assert states[1].header.stamp_nanos - states[0].header.stamp_nanos == pytest.approx(
        1e9 / 30, abs=1
    )
    assert io.stop_reason is not None and "node_test" in io.stop_reason
    truths = io.published["ground_truth"]
    assert [t.header.stamp_nanos for t in truths] == [s.header.stamp_nanos for s in states]
    assert truths[-1].object_class == "mug" and truths[-1].in_contact


def test_sensors_share_the_world_stamp(tmp_path: Path) -> None:
    _, wio = _run_world(_scene_file(tmp_path))
    cams = {
        s: make_node(SimBubbleCamera, {"sensor": s}, name=f"{s}_camera") for s in ("left", "right")
    }
    pressures = {
        s: make_node(SimPressure, {"sensor": s}, name=f"{s}_pressure") for s in ("left", "right")
    }
    gripper, gio = make_node(SimGripper, name="gripper")
    for state in wio.published["state"][:3]:
        for node, _ in (*cams.values(), *pressures.values(), (gripper, gio)):
            feed(node, "world", state)
    stamps = [s.header.stamp_nanos for s in wio.published["state"][:3]]
    for side, (_, io) in cams.items():
        images = io.published["image"]
        assert [m.header.stamp_nanos for m in images] == stamps
        assert images[0].sensor == side
        assert images[0].depth_m.shape == (172, 224) and images[0].ir.shape == (172, 224)
        assert [m.header.stamp_nanos for m in io.published["contact_mask"]] == stamps
    for side, (_, io) in pressures.items():
        msgs = io.published["pressure"]
        assert [m.header.stamp_nanos for m in msgs] == stamps
        assert msgs[0].sensor == side and msgs[-1].pressure_pa > 1000.0
    assert [m.header.stamp_nanos for m in gio.published["state"]] == stamps
    assert gio.published["state"][-1].width_m == pytest.approx(0.07)


def test_camera_renders_only_its_scenes_effects(tmp_path: Path) -> None:
    _, wio = _run_world(_scene_file(tmp_path, effects=["membrane", "depth"]))
    cam, io = make_node(SimBubbleCamera, {"sensor": "left"})
    feed(cam, "world", wio.published["state"][-1])
    assert io.published["image"][0].ir.shape == (0, 0)
    assert "contact_mask" not in io.published
    assert set(cam.renderer.calls) == {"membrane", "depth"}
    pressure, pio = make_node(SimPressure, {"sensor": "left"})
    feed(pressure, "world", wio.published["state"][-1])
    assert "pressure" not in pio.published
    assert "ground_truth" not in wio.published


def test_supervisor_commands_close_the_jaws(tmp_path: Path) -> None:
    scene = _scene_file(tmp_path, duration_secs=2.0, gripper={"initial_width_m": 0.11})
    world, io = make_node(WorldNode, {"scene": scene}, name="world", now_nanos=START)
    io.advance(0.1)
    feed(
        world,
        "command",
        GripperCommand(
            header=Header(), command="grasp", width_m=0.07, speed_m_per_s=0.1, force_n=10.0
        ),
    )
    io.advance(1.5)
    last = io.published["state"][-1]
    assert last.gripper_state == "holding"
    assert last.force_n == pytest.approx(10.0, rel=0.03)
    assert all(last.in_contact)
    speeds = [s.speed_m_per_s for s in io.published["state"]]
    assert max(speeds) == pytest.approx(0.1, rel=1e-6)


def test_bad_params_name_the_field(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="sensor"):
        make_node(SimBubbleCamera, {"sensor": "middle"})
    with pytest.raises(ValueError, match="scene"):
        make_node(WorldNode, {"scene": str(tmp_path / "missing.yaml")})
    with pytest.raises(ValueError, match="effects"):
        make_node(WorldNode, {"scene": _scene_file(tmp_path), "effects": ["nope"]})


def test_world_state_round_trips_the_snapshot(tmp_path: Path) -> None:
    import sim
    from sim.wire import from_message, to_message

    scene = sim.load_scene(_scene_file(tmp_path))
    world = sim.World(scene)
    for _ in range(5):
        snap = world.step()
    msg = to_message(snap, scene, 42)
    assert isinstance(msg, WorldState)
    back = from_message(msg)
    np.testing.assert_array_equal(back.tool_from_object, snap.tool_from_object)
    assert back.in_contact == snap.in_contact and back.width_m == snap.width_m
    for side in ("left", "right"):
        assert (back.anchors[side] is None) == (snap.anchors[side] is None)


def test_node_images_are_bit_identical_to_the_library(tmp_path: Path) -> None:
    import sim

    scene_path = _scene_file(
        tmp_path, effects=["membrane", "depth", "ir", "tof_noise", "dot_pattern"]
    )
    _, wio = _run_world(scene_path)
    cam, io = make_node(SimBubbleCamera, {"sensor": "right"})
    state = wio.published["state"][4]
    feed(cam, "world", state)
    node_image = io.published["image"][0]
    lib_image = sim.render(scene_path, state.time_secs).images["right"]
    assert node_image.depth_m.tobytes() == lib_image.depth_m.tobytes()
    assert node_image.ir.tobytes() == lib_image.ir.tobytes()


def test_world_publishes_its_wrench_only_when_the_scene_lists_it(tmp_path: Path) -> None:
    effects = ["membrane", "depth", "pressure", "gripper", "wrench"]
    _, io = _run_world(_scene_file(tmp_path, effects=effects))
    wrenches = io.published["wrench"]
    states = io.published["state"]
    assert [w.header.stamp_nanos for w in wrenches] == [s.header.stamp_nanos for s in states]
    last = wrenches[-1]
    assert last.source == "sim" and last.bubble_force_n[0, 0] > 0 > last.bubble_force_n[1, 0]
    np.testing.assert_allclose(last.object_force_n, -last.bubble_force_n.sum(axis=0))
    _, plain = _run_world(_scene_file(tmp_path))
    assert "wrench" not in plain.published
