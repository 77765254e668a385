"""Contact patch: which pixels of each bubble are pressed, as one grasp cloud in the tool frame.

The paper's naive contact filter (section "Proximity Pose Estimation"): a difference
image against each bubble's no-contact reference, thresholded. Here, per bubble:

1. Reference: the depth of the free bubble, averaged over frames taken while the
   gripper is open and still (the node decides when; :meth:`ContactPatcher.update_reference`
   averages, :meth:`ContactPatcher.clear_reference` forgets). Pixels invalid in every
   reference frame stay invalid.
2. Difference ``reference - depth`` (contact pushes the membrane towards the camera, so
   depth falls), NaN pixels excluded, thresholded at ``threshold_m``.
3. A small morphological opening, then connected components under ``min_component_px``
   dropped (docs/facts.md: 4.8-8.5 mm thresholds, ~150 px blobs, a small opening).
4. The kept pixels back-projected with the camera intrinsics and moved into the tool frame
   with ``geometry.gripper.tool_from_sensor(side, width_m)`` at the measured opening.

Both bubbles' points are concatenated, with ``bubble`` 0 for left and 1 for right.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Annotated, Generic, TypeVar

import cv2
import msgspec
import numpy as np
from msgspec import Meta

from geometry.camera import PinholeCamera
from geometry.gripper import SIDES

T = TypeVar("T")


class ContactParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Contact filter knobs."""

    threshold_m: Annotated[
        float,
        Meta(
            gt=0.0, description="depth decrease that counts as contact (docs/facts.md: 4.8-8.5 mm)."
        ),
    ] = 0.005
    min_component_px: Annotated[
        int, Meta(ge=0, description="connected components smaller than this are dropped.")
    ] = 150
    opening_px: Annotated[
        int, Meta(ge=0, description="side of the square opening kernel (0 or 1: no opening).")
    ] = 3
    max_points: Annotated[
        int,
        Meta(
            ge=1, description="the grasp cloud is subsampled (evenly) to at most this many points."
        ),
    ] = 30000


def contact_mask(depth_m: np.ndarray, reference_m: np.ndarray, params: ContactParams) -> np.ndarray:
    """Boolean mask of pressed pixels: the difference image, thresholded and cleaned.

    NaN in either image (invalid pixel) is never contact.
    """
    depth = np.asarray(depth_m, dtype=np.float32)
    ref = np.asarray(reference_m, dtype=np.float32)
    if depth.shape != ref.shape:
        raise ValueError(f"depth_m shape {depth.shape} differs from reference {ref.shape}")
    with np.errstate(invalid="ignore"):
        raw = (ref - depth) > params.threshold_m  # NaN compares False
    mask: np.ndarray = raw.astype(np.uint8)
    if params.opening_px > 1:
        kernel = np.ones((params.opening_px, params.opening_px), np.uint8)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    if params.min_component_px > 1 and mask.any():
        count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        keep = np.zeros(count, dtype=bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= params.min_component_px
        mask = keep[labels].astype(np.uint8)
    return mask.astype(bool)


def mask_points_in_tool(
    depth_m: np.ndarray,
    mask: np.ndarray,
    camera: PinholeCamera,
    tool_from_sensor: np.ndarray,
) -> np.ndarray:
    """Back-project the masked, valid pixels and move them into the tool frame, (M, 3) float32."""
    pts = camera.depth_to_points(depth_m)[mask]
    pts = pts[np.all(np.isfinite(pts), axis=1)].astype(np.float64)
    out: np.ndarray = pts @ tool_from_sensor[:3, :3].T + tool_from_sensor[:3, 3]
    return out.astype(np.float32)


@dataclass
class _Reference:
    total_m: np.ndarray
    count: np.ndarray

    def mean(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(
                self.count > 0, self.total_m / np.maximum(self.count, 1), np.nan
            ).astype(np.float32)


@dataclass(frozen=True)
class GraspCloud:
    """One extraction: the concatenated cloud and each bubble's mask."""

    points_in_tool: np.ndarray  # (N, 3) float32
    bubble: np.ndarray  # (N,) uint8: 0 left, 1 right
    masks: dict[str, np.ndarray]  # per side, (H, W) bool


class ContactPatcher:
    """Holds the free-bubble references and turns depth pairs into grasp clouds."""

    def __init__(self, params: ContactParams | None = None) -> None:
        self.params = params or ContactParams()
        self._refs: dict[str, _Reference] = {}

    def has_reference(self, side: str) -> bool:
        return side in self._refs

    def clear_reference(self, side: str | None = None) -> None:
        """Forget one side's reference, or both."""
        for s in SIDES if side is None else (side,):
            self._refs.pop(s, None)

    def update_reference(self, side: str, depth_m: np.ndarray) -> None:
        """Add one free-bubble frame to ``side``'s reference (a running mean per pixel)."""
        depth = np.asarray(depth_m, dtype=np.float64)
        valid = np.isfinite(depth) & (depth > 0)
        ref = self._refs.get(side)
        if ref is None or ref.total_m.shape != depth.shape:
            ref = _Reference(np.zeros(depth.shape), np.zeros(depth.shape))
            self._refs[side] = ref
        ref.total_m += np.where(valid, depth, 0.0)
        ref.count += valid

    def reference(self, side: str) -> np.ndarray | None:
        """The current reference depth of ``side`` (NaN where never valid), or None."""
        ref = self._refs.get(side)
        return None if ref is None else ref.mean()

    def extract(
        self, frames: dict[str, tuple[np.ndarray, PinholeCamera, np.ndarray]]
    ) -> GraspCloud:
        """The grasp cloud from each side's ``(depth_m, camera, tool_from_sensor)``.

        ``tool_from_sensor`` is the camera's 4x4 pose in the tool frame when the frame was
        taken: the geometry of the data itself (``ToFImage.tool_from_sensor``), not a
        default mount. Sides without a reference contribute an empty mask and no points.
        """
        chunks: list[np.ndarray] = []
        sides: list[np.ndarray] = []
        masks: dict[str, np.ndarray] = {}
        for k, side in enumerate(SIDES):
            if side not in frames:
                continue
            depth, camera, pose = frames[side]
            ref = self.reference(side)
            if ref is None or ref.shape != np.shape(depth):
                masks[side] = np.zeros(np.shape(depth), dtype=bool)
                continue
            mask = contact_mask(depth, ref, self.params)
            masks[side] = mask
            pts = mask_points_in_tool(depth, mask, camera, pose)
            chunks.append(pts)
            sides.append(np.full(len(pts), k, dtype=np.uint8))
        points = np.concatenate(chunks) if chunks else np.zeros((0, 3), np.float32)
        bubble = np.concatenate(sides) if sides else np.zeros(0, np.uint8)
        if len(points) > self.params.max_points:
            # Even stride keeps both bubbles' shares and is deterministic.
            idx = np.linspace(0, len(points) - 1, self.params.max_points).astype(int)
            points, bubble = points[idx], bubble[idx]
        return GraspCloud(points.astype(np.float32), bubble, masks)


class StampedHistory(Generic[T]):
    """What something was at a given stamp: the last value stamped at or before it.

    Nodes ask what the gripper was doing when a camera frame was taken (open and still:
    a free-bubble frame; closed on the object: the tare), by the frame's stamp, not by
    the newest state received: on a loaded machine small gripper messages overtake the
    images, and a frame judged by a newer state would be misjudged. With no value that
    old, the newest answers.
    """

    def __init__(self, initial: T, maxlen: int = 64) -> None:
        self.latest = initial
        self._items: deque[tuple[int, T]] = deque(maxlen=maxlen)

    def record(self, stamp_nanos: int, value: T) -> None:
        self.latest = value
        self._items.append((stamp_nanos, value))

    def at(self, stamp_nanos: int) -> T:
        """The value at ``stamp_nanos`` (see the class docstring)."""
        value = self.latest
        for stamp, item in self._items:
            if stamp > stamp_nanos:
                break
            value = item
        return value


class InstantPairs(Generic[T]):
    """The two bubbles' items of one instant: each waits, however late, for its partner.

    Items are keyed by their frame's stamp, each side's arriving in stamp order (one
    publisher, one socket), however far one side trails the other. An item pairs with
    the other side's oldest waiting item if that is within ``skew_nanos`` of it; the
    other side's items older than that can never pair (this side has moved past them:
    their partners were dropped upstream) and are counted in ``lost``, as is an item
    pushed out when ``history`` items of one side wait (the other side sends nothing).
    Pairing each side's newest item instead would put two instants into one estimate
    when one camera lags: a cloud where the object never was, a load off by its change
    between the frames.
    """

    def __init__(self, history: int) -> None:
        self.history = history
        self.waiting: dict[str, deque[tuple[int, T]]] = {"left": deque(), "right": deque()}
        self.lost = 0

    def wait(self, side: str, stamp_nanos: int, item: T) -> None:
        """Keep ``item`` for a partner without looking for one now."""
        mine = self.waiting[side]
        mine.append((stamp_nanos, item))
        if len(mine) > self.history:
            mine.popleft()
            self.lost += 1

    def match(self, side: str, stamp_nanos: int, item: T, skew_nanos: float) -> T | None:
        """The other side's item of this instant, or None (``item`` then waits)."""
        others = self.waiting["right" if side == "left" else "left"]
        while others and others[0][0] < stamp_nanos - skew_nanos:
            others.popleft()
            self.lost += 1
        if not others or others[0][0] > stamp_nanos + skew_nanos:
            self.wait(side, stamp_nanos, item)
            return None
        return others.popleft()[1]
