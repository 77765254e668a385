"""The viewers draw each camera where its frames say they were taken (calibrated or CAD)."""

from __future__ import annotations

import numpy as np

from geometry.gripper import tool_from_sensor
from geometry.mount import CameraMounts
from geometry.se3 import make_pose, rotation_about
from messages.base import Header
from messages.types import ToFImage
from viz.foxglove_export import convert
from viz.shapes import camera_pose


def frame(pose: np.ndarray) -> ToFImage:
    return ToFImage(
        header=Header(stamp_nanos=5, frame_id="left_sensor"),
        sensor="left",
        depth_m=np.full((4, 5), 0.08, np.float32),
        ir=np.zeros((4, 5), np.uint16),
        fx_px=100.0,
        fy_px=100.0,
        cx_px=2.0,
        cy_px=1.5,
        tool_from_sensor=pose,
    )


def test_a_placed_frame_is_drawn_at_its_own_pose_and_an_unplaced_one_at_the_cad_mount() -> None:
    off = make_pose(rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(2.0)), [0.002, 0, 0])
    cad = CameraMounts().mount("left")
    calibrated = CameraMounts({"left": cad @ off}).tool_from_sensor("left", 0.06)
    assert np.allclose(camera_pose("left", 0.09, frame(calibrated)), calibrated)
    assert np.allclose(
        camera_pose("left", 0.09, frame(np.zeros((4, 4)))), tool_from_sensor("left", 0.09)
    )
    assert np.allclose(camera_pose("left", 0.09), tool_from_sensor("left", 0.09))
    placed = convert("left_camera/image", frame(calibrated))
    assert [topic for topic, kind, _ in placed if kind == "FrameTransform"] == ["/tf"]
    unplaced = convert("left_camera/image", frame(np.zeros((4, 4))))
    assert not [kind for _, kind, _ in unplaced if kind == "FrameTransform"]
