"""contact_patch places points by the camera pose each frame carries, or refuses the frame."""

from __future__ import annotations

import numpy as np

from geometry.camera import PinholeCamera
from geometry.gripper import GripperGeometry, tool_from_sensor
from messages.base import Header
from messages.types import GripperState, ToFImage
from nodes.contact_patch import ContactPatchNode
from runtime.testing import feed, make_node

CAM = PinholeCamera.from_fov(64, 48)


def tof_image(side: str, depth: np.ndarray, stamp: int, pose: np.ndarray) -> ToFImage:
    """A ToFImage of ``depth`` from camera ``CAM`` mounted at ``pose`` (tool_from_sensor)."""
    return ToFImage(
        header=Header(stamp_nanos=stamp),
        sensor=side,
        depth_m=depth.astype(np.float32),
        ir=np.zeros(depth.shape, np.uint16),
        fx_px=CAM.fx_px,
        fy_px=CAM.fy_px,
        cx_px=CAM.cx_px,
        cy_px=CAM.cy_px,
        tool_from_sensor=pose,
    )


def _patch_points(poses: dict[str, np.ndarray]) -> tuple[dict, object]:
    node, io = make_node(
        ContactPatchNode, {"contact": {"min_component_px": 20}, "reference_frames": 1}
    )
    free = np.full(CAM.shape, 0.08, np.float32)
    pressed = free.copy()
    pressed[10:30, 10:30] = 0.07
    feed(node, "gripper", GripperState(header=Header(), width_m=0.11, speed_m_per_s=0.0, force_n=0))
    for side in ("left", "right"):
        feed(node, side, tof_image(side, free, 0, poses[side]))
    for side in ("left", "right"):
        feed(node, side, tof_image(side, pressed, 1, poses[side]))
    return io.published, node


def test_points_follow_the_mount_each_frame_carries() -> None:
    """A scene with another camera mount: its frames say so and the patch follows them
    (no module-wide default geometry is assumed)."""
    width = 0.07
    default = {s: tool_from_sensor(s, width) for s in ("left", "right")}
    other_geometry = GripperGeometry(camera_back_m=0.03, camera_pitch_deg=20.0)
    other = {s: other_geometry.tool_from_sensor(s, width) for s in ("left", "right")}
    assert not np.allclose(default["left"], other["left"])
    for poses in (default, other):
        published, _ = _patch_points(poses)
        patch = published["patch"][-1]
        left = patch.points_in_tool[patch.bubble == 0]
        assert len(left) == 400
        pts_sensor = CAM.depth_to_points(np.full(CAM.shape, 0.07, np.float32))[10:30, 10:30]
        pts_sensor = pts_sensor.reshape(-1, 3)
        pose = poses["left"]
        want = pts_sensor @ pose[:3, :3].T + pose[:3, 3]
        np.testing.assert_allclose(np.sort(left, axis=0), np.sort(want, axis=0), atol=1e-5)


def test_frames_without_a_mount_are_refused() -> None:
    unknown = np.zeros((4, 4))
    published, node = _patch_points({"left": unknown, "right": unknown})
    assert "patch" not in published


def test_a_patch_pairs_frames_of_one_instant_when_a_camera_lags() -> None:
    """The right camera lags two frames: each patch waits for the right frame of the
    left one's instant, never mixing the bubbles' views of different instants."""
    node, io = make_node(ContactPatchNode, {"contact": {"min_component_px": 20}})
    poses = {s: tool_from_sensor(s, 0.07) for s in ("left", "right")}
    feed(node, "gripper", GripperState(header=Header(), width_m=0.07, speed_m_per_s=0.0, force_n=0))
    period = 33_333_333
    depth = np.full(CAM.shape, 0.08, np.float32)
    for k in range(3):
        feed(node, "left", tof_image("left", depth, k * period, poses["left"]))
    assert "patch" not in io.published
    for k in range(3):
        feed(node, "right", tof_image("right", depth, k * period + 1_000_000, poses["right"]))
    stamps = [p.header.stamp_nanos for p in io.published["patch"]]
    assert stamps == [k * period + 1_000_000 for k in range(3)]
    # Frames more than half a frame period apart never make a patch; within it they do
    # (two free-running cameras).
    feed(node, "left", tof_image("left", depth, 10 * period, poses["left"]))
    feed(node, "right", tof_image("right", depth, 11 * period, poses["right"]))
    assert len(io.published["patch"]) == 3
    feed(node, "left", tof_image("left", depth, 11 * period + period // 3, poses["left"]))
    assert io.published["patch"][-1].header.stamp_nanos == 11 * period + period // 3


def test_free_frames_that_arrive_after_the_grasp_began_still_make_the_reference() -> None:
    """On a loaded machine the gripper's state overtakes the images: frames taken open
    and still, received after the fingers started closing, are still free frames."""
    node, io = make_node(
        ContactPatchNode, {"contact": {"min_component_px": 20}, "reference_frames": 1}
    )
    poses = {s: tool_from_sensor(s, 0.07) for s in ("left", "right")}
    free = np.full(CAM.shape, 0.08, np.float32)
    pressed = free.copy()
    pressed[10:30, 10:30] = 0.07
    for stamp, width, speed in ((0, 0.11, 0.0), (100, 0.1, 0.05), (200, 0.07, 0.0)):
        state = GripperState(
            header=Header(stamp_nanos=stamp), width_m=width, speed_m_per_s=speed, force_n=0
        )
        feed(node, "gripper", state)
    for stamp, depth in ((10, free), (300, pressed)):
        for side in ("left", "right"):
            feed(node, side, tof_image(side, depth, stamp, poses[side]))
    patch = io.published["patch"][-1]
    assert patch.header.stamp_nanos == 300 and len(patch.points_in_tool) == 2 * 400
