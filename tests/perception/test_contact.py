"""Contact patch: difference image, threshold, NaN pixels, small blobs, tool-frame points."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from geometry.camera import PinholeCamera
from geometry.gripper import tool_from_sensor
from perception.contact import ContactParams, ContactPatcher, InstantPairs, contact_mask
from runtime.params import build_params

CAM = PinholeCamera.from_fov(64, 48)


def _free() -> np.ndarray:
    return np.full(CAM.shape, 0.08, np.float32)


def _pressed() -> np.ndarray:
    depth = _free()
    rows, cols = np.mgrid[: CAM.height_px, : CAM.width_px]
    disk = (rows - 24) ** 2 + (cols - 20) ** 2 < 10**2
    depth[disk] = 0.07  # pushed 10 mm towards the camera
    depth[2:4, 50:52] = 0.06  # a 4 px blob: noise, dropped
    depth[24, 20] = np.nan  # an invalid pixel inside the patch
    return depth, disk


def test_mask_thresholds_and_cleans() -> None:
    depth, disk = _pressed()
    mask = contact_mask(depth, _free(), ContactParams(min_component_px=20, opening_px=0))
    assert not mask[2:4, 50:52].any()  # small component removed
    assert not mask[24, 20]  # NaN is never contact
    assert mask.sum() == disk.sum() - 1
    # Below threshold: nothing.
    assert not contact_mask(_free() - 0.003, _free(), ContactParams()).any()
    # NaN reference pixels are never contact either.
    ref = _free()
    ref[:, :30] = np.nan
    assert not contact_mask(depth, ref, ContactParams(min_component_px=0, opening_px=0))[
        :, :30
    ].any()


def test_patch_points_in_tool_frame_and_bubble_labels() -> None:
    patcher = ContactPatcher(ContactParams(min_component_px=20, opening_px=3))
    for side in ("left", "right"):
        assert not patcher.has_reference(side)
        for _ in range(3):
            patcher.update_reference(side, _free())
    depth, disk = _pressed()
    frames = {side: (depth, CAM, tool_from_sensor(side, 0.07)) for side in ("left", "right")}
    cloud = patcher.extract(frames)
    n = int(cloud.masks["left"].sum())
    assert n > 200 and len(cloud.points_in_tool) == 2 * n
    assert cloud.points_in_tool.dtype == np.float32 and cloud.bubble.dtype == np.uint8
    np.testing.assert_array_equal(np.bincount(cloud.bubble), [n, n])
    # Every left point equals the back-projected pixel moved by tool_from_sensor.
    pose = tool_from_sensor("left", 0.07)
    pts_sensor = CAM.depth_to_points(depth)[cloud.masks["left"]]
    want = pts_sensor @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(cloud.points_in_tool[cloud.bubble == 0], want, atol=1e-6)
    # The left bubble sits at tool +x, the right at -x.
    assert cloud.points_in_tool[cloud.bubble == 0, 0].mean() > 0
    assert cloud.points_in_tool[cloud.bubble == 1, 0].mean() < 0


LEFT_AT_50_MM = tool_from_sensor("left", 0.05)


def test_no_reference_all_nan_and_subsampling() -> None:
    patcher = ContactPatcher(ContactParams(max_points=100))
    depth, _ = _pressed()
    cloud = patcher.extract({"left": (depth, CAM, LEFT_AT_50_MM)})
    assert len(cloud.points_in_tool) == 0 and not cloud.masks["left"].any()
    patcher.update_reference("left", _free())
    nan_img = np.full(CAM.shape, np.nan, np.float32)
    assert len(patcher.extract({"left": (nan_img, CAM, LEFT_AT_50_MM)}).points_in_tool) == 0
    cloud = patcher.extract({"left": (depth, CAM, LEFT_AT_50_MM)})
    assert len(cloud.points_in_tool) == 100
    patcher.clear_reference("left")
    assert patcher.reference("left") is None


def test_reference_averages_valid_frames_only() -> None:
    patcher = ContactPatcher()
    a = _free()
    b = _free() + 0.002
    b[0, 0] = np.nan
    patcher.update_reference("right", a)
    patcher.update_reference("right", b)
    ref = patcher.reference("right")
    assert ref[0, 0] == pytest.approx(0.08)
    assert ref[1, 1] == pytest.approx(0.081)


def test_params_checked() -> None:
    with pytest.raises(ValueError, match="threshold_m"):
        build_params(ContactParams, {"threshold_m": 0.0})
    with pytest.raises(ValueError, match="shape"):
        contact_mask(np.zeros((2, 2)), np.zeros((3, 3)), ContactParams())


def test_instant_pairs_wait_for_a_late_partner_and_count_the_ones_whose_partner_was_lost() -> None:
    pairs: InstantPairs[str] = InstantPairs(history=3)
    assert pairs.match("right", 0, "r0", 5) is None
    assert pairs.match("right", 33, "r33", 5) is None  # the left camera lags two frames
    assert pairs.match("left", 0, "l0", 5) == "r0"
    # Left's frame 33 was dropped upstream: left 66 moves past right 33, which can never
    # pair, and waits for right 66.
    assert pairs.match("left", 66, "l66", 5) is None
    assert pairs.lost == 1
    assert pairs.match("right", 66, "r66", 5) == "l66"
    assert pairs.waiting == {"left": deque(), "right": deque()}
    pairs.wait("left", 100, "l100")  # kept without looking (a node not ready to pair)
    assert pairs.match("right", 101, "r101", 5) == "l100"
    for k in range(5):  # the right camera sends nothing: the oldest waiting go
        assert pairs.match("left", 133 + 33 * k, f"l{k}", 5) is None
    assert pairs.lost == 3 and len(pairs.waiting["left"]) == 3
