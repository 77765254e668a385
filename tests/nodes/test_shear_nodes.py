"""The grasp monitor and shear tracker nodes through FakeIO (no sockets)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import nodes.grasp_monitor  # noqa: F401  (registers the implementations)
import nodes.shear_tracker  # noqa: F401
from bench.shear import angle_error_deg, scored_mask
from messages.base import Header
from messages.shear import ShearReset
from messages.types import GraspState, GripperState, Pressure, ToFImage
from runtime.registry import resolve
from runtime.testing import feed, make_node
from sim.material_flow import SimGrasp, truth


def stamp(secs: float) -> Header:
    return Header(stamp_nanos=int(secs * 1e9))


@pytest.fixture(scope="module")
def scene() -> SimGrasp:
    return SimGrasp()


def image(scene: SimGrasp, sensor: str, secs: float, shift_mm=(0.0, 0.0)) -> ToFImage:
    """A simulated frame of the held mug moved by ``shift_mm`` (tool y, z), restamped."""
    shift_m = (shift_mm[0] / 1000.0, shift_mm[1] / 1000.0)
    msg = scene.instant(shift_m, 0.0, index=int(secs * 30)).images[sensor]
    msg.header = stamp(secs)
    return msg


def grasp_state(secs: float, stable: bool, event: str = "") -> GraspState:
    return GraspState(header=stamp(secs), stable=stable, event=event)


def test_grasp_monitor_node_publishes_events():
    node, io = make_node(resolve("grasp_monitor"), {"dwell_secs": 0.2, "baseline_pa": 1000.0})
    events = []
    for i in range(300):
        t = i / 100.0
        # Squeezed from 0.5 s; the jaws open at 20 mm/s from 2.0 s, the bubbles let go
        # at 2.2 s.
        squeeze = 1.0 if 0.5 <= t < 2.2 else 0.0
        speed = 0.02 if 2.0 <= t < 2.3 else 0.0
        width = 0.05 + 0.02 * min(max(t - 2.0, 0.0), 0.3)
        feed(
            node, "left", Pressure(header=stamp(t), sensor="left", pressure_pa=1000 + 60 * squeeze)
        )
        feed(
            node,
            "right",
            Pressure(header=stamp(t), sensor="right", pressure_pa=1000 + 60 * squeeze),
        )
        feed(
            node,
            "gripper",
            GripperState(header=stamp(t), width_m=width, speed_m_per_s=speed, force_n=0),
        )
    published = io.published["grasp"]
    events = [(m.header.stamp_nanos * 1e-9, m.event) for m in published if m.event]
    assert [e for _, e in events] == ["stable", "released"]
    # Contact once the filtered rise passes 30 Pa (~35 ms), then a 0.2 s dwell.
    assert events[0][0] == pytest.approx(0.5 + 0.035 + 0.2, abs=0.03)
    # 2 mm of opening (the default release_opening_m) at 20 mm/s.
    assert events[1][0] == pytest.approx(2.1, abs=0.02)
    # One state per gripper sample, plus the events raised by pressure samples.
    assert len(published) >= 300
    stable_msgs = [m for m in published if m.stable]
    assert all(m.pressure_rise_left_pa > 30 for m in stable_msgs)


def test_grasp_monitor_rejects_bad_params():
    with pytest.raises(ValueError, match="contact_rise_pa"):
        make_node(resolve("grasp_monitor"), {"contact_rise_pa": -1.0})


@pytest.mark.parametrize("impl", ["shear_tracker.farneback", "shear_tracker.dis"])
def test_shear_tracker_reference_follows_the_grasp(scene, impl):
    node, io = make_node(resolve(impl), {"overlay_every_n": 2})
    feed(node, "left", image(scene, "left", 0.0, (3.0, 0.0)))
    first = io.published["shear"][-1]
    assert first.sensor == "left" and not first.has_reference and not first.direction_defined

    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    # A frame stamped before the stable moment is not taken as the reference.
    feed(node, "left", image(scene, "left", 0.9, (3.0, 0.0)))
    assert not io.published["shear"][-1].has_reference
    feed(node, "left", image(scene, "left", 1.0))  # the reference
    at_ref = io.published["shear"][-1]
    assert at_ref.has_reference and not at_ref.direction_defined
    feed(node, "right", image(scene, "right", 1.0))
    assert io.published["shear"][-1].sensor == "right"

    pull = (-0.8, 0.8)
    feed(node, "left", image(scene, "left", 1.1, pull))
    moved = io.published["shear"][-1]
    rest = scene.instant()
    moved_instant = scene.instant((pull[0] / 1000.0, pull[1] / 1000.0), 0.0, 33)
    mask = scored_mask(rest.images["left"])
    truth_px, truth_m, _ = truth(scene.geometry, scene.camera, rest, moved_instant, "left", mask)
    assert moved.direction_defined
    assert angle_error_deg(moved.direction, truth_px) < 3.0
    assert moved.magnitude_px == pytest.approx(math.hypot(*truth_px), rel=0.15)
    # shear_m is along the tool's y and z (the default shear_frame), like the truth.
    assert angle_error_deg(moved.shear_m, truth_m) < 5.0

    feed(node, "grasp", grasp_state(2.0, False, "released"))
    feed(node, "left", image(scene, "left", 2.1, pull))
    assert not io.published["shear"][-1].has_reference

    overlays = io.published["overlay"]
    assert overlays, "an overlay every second frame per bubble"
    assert overlays[0].image.shape == (*scene.camera.shape, 3)
    assert overlays[0].image.dtype == np.uint8


def test_shear_tracker_reset_retakes_the_reference(scene):
    node, io = make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": 0})
    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    feed(node, "left", image(scene, "left", 1.0))
    feed(node, "right", image(scene, "right", 1.0))
    feed(node, "left", image(scene, "left", 1.1, (2.0, 0.0)))
    assert io.published["shear"][-1].direction_defined

    feed(node, "reset", ShearReset(header=stamp(1.2), sensor="left"))
    feed(node, "left", image(scene, "left", 1.3, (2.0, 0.0)))  # new reference
    feed(node, "left", image(scene, "left", 1.4, (2.0, 0.0)))
    assert not io.published["shear"][-1].direction_defined
    feed(node, "right", image(scene, "right", 1.4, (2.0, 0.0)))  # right kept its reference
    right = io.published["shear"][-1]
    assert right.sensor == "right" and right.direction_defined
    assert "overlay" not in io.published


def test_shear_tracker_stable_without_event_still_takes_a_reference(scene):
    node, io = make_node(resolve("shear_tracker.dis"), {"overlay_every_n": 0})
    feed(node, "grasp", grasp_state(0.5, True))  # a late subscriber sees stable, no event
    feed(node, "left", image(scene, "left", 0.6))
    assert io.published["shear"][-1].has_reference


def test_shear_tracker_params_check_their_method():
    with pytest.raises(ValueError, match="method"):
        make_node(resolve("shear_tracker.dis"), {"method": "farneback"})
    with pytest.raises(ValueError, match="overlay_every_n"):
        make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": -1})


def test_shear_tracker_skips_frames_without_ir(scene):
    node, io = make_node(resolve("shear_tracker.farneback"))
    msg = image(scene, "left", 0.1)
    msg.ir = np.zeros((0, 0), np.uint16)
    feed(node, "grasp", grasp_state(0.0, True, "stable"))
    feed(node, "left", msg)
    assert "shear" not in io.published
    feed(node, "left", image(scene, "left", 0.2))
    assert io.published["shear"][-1].has_reference


def test_both_bubbles_report_shear_in_the_tool_frame(scene):
    """The mug moved along tool +y, then +z: both bubbles report it along the same tool
    axis with the same sign, although the cameras face each other (mirrored images)."""
    for axis, shift in ((0, (1.0, 0.0)), (1, (0.0, 1.0))):
        node, io = make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": 0})
        feed(node, "grasp", grasp_state(1.0, True, "stable"))
        estimates = {}
        for sensor in ("left", "right"):
            feed(node, sensor, image(scene, sensor, 1.0))
            feed(node, sensor, image(scene, sensor, 1.5, shift))
            estimates[sensor] = io.published["shear"][-1]
        for est in estimates.values():
            assert est.shear_m[axis] > 0.5e-3 and abs(est.shear_m[1 - axis]) < 0.1e-3
        if axis == 0:  # across the fingers: image rows, mirrored between the two cameras
            assert estimates["left"].shear_px[1] * estimates["right"].shear_px[1] < 0
        else:  # along the fingers: image columns, the same way in both
            assert estimates["left"].shear_px[0] * estimates["right"].shear_px[0] > 0


def test_shear_tracker_retakes_the_reference_when_the_image_size_changes(scene):
    node, io = make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": 0})
    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    feed(node, "left", image(scene, "left", 1.0))
    small = image(scene, "left", 1.1)
    small.ir = np.ascontiguousarray(small.ir[::2, ::2])
    small.depth_m = np.ascontiguousarray(small.depth_m[::2, ::2])
    feed(node, "left", small)
    result = io.published["shear"][-1]
    assert result.has_reference and not result.direction_defined


def test_shear_tracker_refuses_frames_without_the_camera_mount(scene):
    """shear_frame 'tool' needs the frame's tool_from_sensor; a frame without it (all
    zeros: the source does not know its mount) is refused, not read with a default."""
    node, io = make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": 0})
    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    msg = image(scene, "left", 1.0)
    msg.tool_from_sensor = np.zeros((4, 4))
    feed(node, "left", msg)
    assert "shear" not in io.published
    node, io = make_node(
        resolve("shear_tracker.farneback"), {"overlay_every_n": 0, "shear_frame": "membrane"}
    )
    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    feed(node, "left", msg)
    assert io.published["shear"][-1].has_reference


def test_shear_in_the_tool_frame_follows_the_mount_the_frame_carries(scene):
    """A scene whose cameras are mounted turned about the optical axis: the frames say
    so, and the tool-frame shear stays along the tool axis the mug moved on."""
    node, io = make_node(resolve("shear_tracker.farneback"), {"overlay_every_n": 0})
    feed(node, "grasp", grasp_state(1.0, True, "stable"))
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # the image turned 90 deg about the optical axis
    for secs, shift in ((1.0, (0.0, 0.0)), (1.5, (1.0, 0.0))):
        msg = image(scene, "left", secs, shift)
        msg.ir = np.ascontiguousarray(np.rot90(msg.ir))
        msg.depth_m = np.ascontiguousarray(np.rot90(msg.depth_m))
        msg.fx_px, msg.fy_px = msg.fy_px, msg.fx_px
        h, w = msg.ir.shape
        msg.cx_px, msg.cy_px = (w - 1) / 2.0, (h - 1) / 2.0
        msg.tool_from_sensor = msg.tool_from_sensor @ turn
        feed(node, "left", msg)
    est = io.published["shear"][-1]
    assert est.shear_m[0] > 0.5e-3 and abs(est.shear_m[1]) < 0.15e-3
