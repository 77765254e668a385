"""``contact_patch``: both bubbles' depth images to one grasp cloud in the tool frame.

Ports:
    inputs: ``left``, ``right`` (ToFImage), ``gripper`` (GripperState).
    outputs: ``patch`` (ContactPatch: ``points_in_tool`` float32 (N, 3), ``bubble`` uint8
        (N,), 0 left / 1 right; header frame_id ``tool``, stamp of the newer image),
        ``mask`` (MaskImage, one per bubble per patch, 255 = contact; ``sensor`` says which).

A patch is made of one frame of each bubble taken at the same instant: stamps at most
half a frame period apart (the shortest interval seen between a camera's frames, of the
slower camera), or ``max_skew_secs`` when set. The simulator stamps both with its
world's instant; two free-running cameras at one rate are up to half a frame apart. A frame waits (the last
``PAIR_HISTORY`` of each bubble are kept) until its partner arrives; then the pair is
published and older frames are dropped. Pairing the newest frame of each instead would,
on a loaded machine where one camera lags, put the two bubbles' views of a moving object
from different instants into one cloud: a pose where the object never was. Each frame's points go to the tool frame by the camera pose
the frame carries (``ToFImage.tool_from_sensor``): the gripper geometry of the data's own
scene or calibration. A frame without it is refused, with a warning naming the field. The free-bubble reference is (re)captured whenever the
gripper is open (``width_m >= reference_min_width_m``) and still (speed under
``reference_max_speed_m_per_s``): on entering that state the old reference is dropped
and the next ``reference_frames`` frames of each bubble are averaged into a new one. A
frame counts as free by the gripper's state at the frame's stamp, not by the newest
state received: on a loaded machine the small gripper messages overtake the images, and
the free frames taken before a grasp would otherwise arrive after it began and be lost.
Until a bubble has a reference it contributes no points. The logic lives in
:mod:`perception.contact`.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from geometry.camera import PinholeCamera
from messages.base import Header
from messages.types import ContactPatch, GripperState, MaskImage, Side, ToFImage, pose_is_known
from perception.contact import ContactParams, ContactPatcher, InstantPairs, StampedHistory
from runtime.node import Node
from runtime.registry import register

PAIR_HISTORY = 8  # frames of each bubble kept while waiting for the other's
GRIPPER_HISTORY = 64  # gripper states kept to tell whether a frame was taken open and still


class ContactPatchParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The contact filter's knobs (``contact``) plus when to take the free-bubble reference."""

    contact: Annotated[
        ContactParams,
        Meta(
            description=(
                "the filter (``perception.contact.ContactParams``), e.g. ``{contact: "
                "{threshold_m: 0.006}}`` in a graph file."
            )
        ),
    ] = msgspec.field(default_factory=ContactParams)
    reference_min_width_m: Annotated[
        float, Meta(ge=0.0, description="the gripper counts as open from this opening on.")
    ] = 0.1
    reference_max_speed_m_per_s: Annotated[
        float, Meta(ge=0.0, description="... and as still below this finger speed.")
    ] = 0.001
    reference_frames: Annotated[
        int, Meta(ge=1, description="free frames averaged into each bubble's reference.")
    ] = 5
    max_skew_secs: Annotated[
        float,
        Meta(
            ge=0.0,
            description=(
                "the most two frames' stamps may differ to make one patch; 0: half the "
                "slower camera's frame period, measured from the stamps."
            ),
        ),
    ] = 0.0


@register("contact_patch")
class ContactPatchNode(Node):
    """Difference-image contact patch of both bubbles (paper's naive filter)."""

    Params = ContactPatchParams
    inputs = {"left": ToFImage, "right": ToFImage, "gripper": GripperState}
    outputs = {"patch": ContactPatch, "mask": MaskImage}

    def setup(self) -> None:
        self.patcher = ContactPatcher(self.params.contact)
        self.pairs: InstantPairs[ToFImage] = InstantPairs(PAIR_HISTORY)
        self.last_stamp: dict[str, int] = {}
        self.period_nanos = {"left": 0, "right": 0}  # shortest interval seen; 0: none yet
        self.gripper_seen = False
        self.warned_mount: set[str] = set()
        self.open_still = False
        self.gripper_states = StampedHistory(False, GRIPPER_HISTORY)
        self.ref_frames = {"left": 0, "right": 0}

    def on_gripper(self, msg: GripperState) -> None:
        prm = self.params
        self.gripper_seen = True
        open_still = (
            msg.width_m >= prm.reference_min_width_m
            and abs(msg.speed_m_per_s) <= prm.reference_max_speed_m_per_s
        )
        if open_still and not self.open_still:
            self.patcher.clear_reference()
            self.ref_frames = {"left": 0, "right": 0}
        self.open_still = open_still
        self.gripper_states.record(msg.header.stamp_nanos, open_still)

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, side: Side, msg: ToFImage) -> None:
        if not pose_is_known(msg.tool_from_sensor):
            if side not in self.warned_mount:
                self.io.log.warning(
                    "%s: %s frames carry no `tool_from_sensor` (the camera's pose in the "
                    "tool frame); refused: their points cannot be placed in the tool frame",
                    self.name,
                    side,
                )
                self.warned_mount.add(side)
            return
        if (
            self.gripper_states.at(msg.header.stamp_nanos)
            and self.ref_frames[side] < self.params.reference_frames
        ):
            self.patcher.update_reference(side, msg.depth_m)
            self.ref_frames[side] += 1
        other = "right" if side == "left" else "left"
        stamp = msg.header.stamp_nanos
        step = stamp - self.last_stamp.get(side, stamp)
        if step > 0 and (self.period_nanos[side] == 0 or step < self.period_nanos[side]):
            self.period_nanos[side] = step
        self.last_stamp[side] = stamp
        skew = self.params.max_skew_secs * 1e9 or 0.5 * max(self.period_nanos.values())
        if not self.gripper_seen:
            self.pairs.wait(side, stamp, msg)
            return
        partner = self.pairs.match(side, stamp, msg, skew)
        if partner is not None:
            self._publish({side: msg, other: partner})

    def _publish(self, pair: dict[str, ToFImage]) -> None:
        frames = {
            s: (m.depth_m, PinholeCamera.from_frame(m), m.tool_from_sensor) for s, m in pair.items()
        }
        cloud = self.patcher.extract(frames)
        stamp = max(m.header.stamp_nanos for m in pair.values())
        self.io.publish(
            "patch",
            ContactPatch(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                points_in_tool=np.ascontiguousarray(cloud.points_in_tool, dtype=np.float32),
                bubble=np.ascontiguousarray(cloud.bubble, dtype=np.uint8),
            ),
        )
        sides: tuple[Side, ...] = ("left", "right")
        for side in sides:
            mask = cloud.masks.get(side)
            if mask is None:
                continue
            self.io.publish(
                "mask",
                MaskImage(
                    header=Header(stamp_nanos=stamp, frame_id=f"{side}_sensor"),
                    sensor=side,
                    mask=np.where(mask, 255, 0).astype(np.uint8),
                ),
            )
