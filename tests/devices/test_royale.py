"""``bubble_camera.royale`` with a stand-in for the royale SDK: conversion and errors."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from devices.royale import convert
from geometry.camera import PinholeCamera
from geometry.gripper import tool_from_sensor
from geometry.se3 import make_pose, rotation_about
from messages.base import Header
from messages.errors import NodeError
from messages.types import GripperState
from nodes.bubble_camera import RoyaleBubbleCamera
from nodes.contact_patch import ContactPatchNode
from runtime.testing import feed, make_node
from sim import render_grasp
from sim.emulated_rig import sdk_points
from sim.royale_sdk import roypy as fake_roypy
from sim.scene import CameraSpec

CAMERA: PinholeCamera = CameraSpec().intrinsics()


def _points(height: int = 171, width: int = 224) -> np.ndarray:
    """x, y, z, noise, gray, confidence per pixel: a flat membrane 80 mm away."""
    pts = np.zeros((height, width, 6))
    pts[..., 2] = 0.08
    pts[..., 3] = 0.001
    pts[..., 4] = np.arange(width)[None, :] * 10.0
    pts[..., 5] = 255
    return pts


def test_invalid_pixels_become_nan_and_gray_becomes_uint16() -> None:
    pts = _points(4, 5)
    pts[0, 0, 5] = 0  # no confidence
    pts[1, 1, 3] = 0.08  # noise over 0.07 m
    pts[2, 2, 2] = 0.0  # no depth
    pts[3, 3, 4] = 70000.0  # beyond 16 bits
    depth, ir = convert(pts)
    assert depth.dtype == np.float32 and ir.dtype == np.uint16
    assert np.isnan(depth[[0, 1, 2], [0, 1, 2]]).all()
    assert np.isfinite(depth).sum() == 20 - 3
    assert depth[3, 4] == np.float32(0.08)
    assert ir[3, 3] == 65535 and ir[0, 4] == 40


def test_node_publishes_frames_with_the_cameras_intrinsics(monkeypatch: pytest.MonkeyPatch) -> None:

    roypy = fake_roypy.module("0005-1203-0034-2215")
    monkeypatch.setitem(sys.modules, "roypy", roypy)
    node, io = make_node(
        RoyaleBubbleCamera,
        {
            "sensor": "left",
            "use_case": "MODE_5_45FPS_500",
            "exposure_us": 300,
            "opening_wait_secs": 0.0,  # no gripper wired: publish at once, without a pose
        },
    )
    camera = roypy.cameras["0005-1203-0034-2215"]
    assert camera.use_case == "MODE_5_45FPS_500" and camera.exposure_us == 300
    pts = _points()
    pts[10, 20, 5] = 0
    camera.emit(pts, stamp_us=1_700_000_000_123_456)
    node.tick()
    (image,) = io.published["image"]
    assert image.depth_m.shape == (171, 224) and image.ir.shape == (171, 224)
    assert np.isnan(image.depth_m[10, 20]) and image.depth_m[0, 0] == np.float32(0.08)
    assert (image.fx_px, image.fy_px, image.cx_px, image.cy_px) == pytest.approx(
        (210.5, 210.9, 111.4, 86.2)
    )
    assert image.header.stamp_nanos == 1_700_000_000_123_456_000
    assert image.sensor == "left" and image.header.frame_id == "left_sensor"
    node.teardown()
    assert not camera.capturing and camera.listener is None


def test_without_roypy_the_error_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "roypy", None)  # import roypy raises ImportError

    with pytest.raises(
        NodeError, match=r"left: the royale SDK's Python binding `roypy`.*PYTHONPATH"
    ):
        make_node(RoyaleBubbleCamera, {"sensor": "left"}, name="left")


def test_unknown_use_case_and_camera_are_listed(monkeypatch: pytest.MonkeyPatch) -> None:

    monkeypatch.setitem(sys.modules, "roypy", fake_roypy.module("A", "B"))
    with pytest.raises(
        NodeError, match=r"need exactly one camera \(or an id\); connected: \['A', 'B'\]"
    ):
        make_node(RoyaleBubbleCamera, {"sensor": "left"})
    with pytest.raises(NodeError, match=r"no use case 'MODE_X'; it offers \['MODE_9_5FPS_2000'"):
        make_node(RoyaleBubbleCamera, {"sensor": "left", "camera_id": "B", "use_case": "MODE_X"})


def test_royale_frames_are_placed_in_the_tool_frame_and_make_a_contact_patch(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The hardware graph's path: the SDK's points, the gripper's opening at the frame's
    stamp, the contact patch. (Before frames carried ``tool_from_sensor`` the contact
    patch refused every one of them: no patch came.)"""
    roypy = fake_roypy.module("CAM-L")
    monkeypatch.setitem(sys.modules, "roypy", roypy)
    camera_node, camera_io = make_node(RoyaleBubbleCamera, {"sensor": "left"})
    camera = roypy.cameras["CAM-L"]
    patch_node, patch_io = make_node(
        ContactPatchNode, {"reference_frames": 1, "contact": {"min_component_px": 20}}
    )
    mug = make_pose(rotation_about(np.array([1.0, 0.0, 0.0]), np.pi / 2))  # axis along tool y
    free = make_pose(trans=np.array([0.0, 0.0, 0.5]))  # far from both bubbles
    for k, (width, pose) in enumerate(((0.11, free), (0.06, mug))):
        stamp = (k + 1) * 100_000_000
        instant = render_grasp("mug", pose, width, effects=("depth", "ir"))
        camera.emit(sdk_points(instant.frames["left"].arrays, CAMERA), stamp_us=stamp // 1000)
        state = GripperState(
            header=Header(stamp_nanos=stamp + 1), width_m=width, speed_m_per_s=0.0, force_n=0.0
        )
        feed(camera_node, "gripper", state)
        feed(patch_node, "gripper", state)
        camera_node.tick()
        image = camera_io.published["image"][-1]
        assert np.allclose(image.tool_from_sensor, tool_from_sensor("left", width), atol=1e-6)
        right = instant.images["right"]
        right.header.stamp_nanos = stamp
        feed(patch_node, "left", image)
        feed(patch_node, "right", right)
    (_, patch) = patch_io.published["patch"]
    left = patch.points_in_tool[patch.bubble == 0]
    assert len(left) > 100
    # On the mug (radius 40 mm about tool y), where the left bubble (tool x > 0) meets it.
    radius = np.hypot(left[:, 0], left[:, 2])
    assert np.median(np.abs(radius - 0.04)) < 0.002 and np.all(left[:, 0] > 0)
