"""``shear_tracker.farneback`` and ``shear_tracker.dis``: shear of both bubbles.

Ports:
    inputs: ``left``, ``right`` (ToFImage; each optional, wire the bubbles you have),
        ``grasp`` (GraspState), ``reset`` (ShearReset, optional).
    outputs: ``shear`` (ShearEstimate, one per bubble per frame; ``sensor`` says which),
        ``overlay`` (OverlayImage: IR with the flow field and the mean-shear arrow, every
        ``overlay_every_n`` frames per bubble).

The reference of each bubble is the first frame stamped at or after the moment the
grasp monitor reports a stable grasp; it is dropped when the grasp is released and
retaken on a ShearReset. Without a reference the estimate says ``has_reference=False``.
The logic is :class:`perception.shear.ShearTracker` (no sockets).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.camera import PinholeCamera
from messages.base import Header
from messages.shear import ShearReset
from messages.types import GraspState, OverlayImage, ShearEstimate, ToFImage
from perception.shear import (
    ShearParams,
    ShearResult,
    ShearTracker,
    draw_overlay,
    tool_basis_in_sensor,
)
from runtime.node import Node
from runtime.registry import register

SENSORS = ("left", "right")


@dataclass(frozen=True, kw_only=True)
class ShearTrackerParams(ShearParams):
    """The flow and mask parameters, plus the frame of ``shear_mm`` and the overlay's.

    Attributes:
        shear_frame: ``"tool"``: ``shear_mm`` is along the tool's y and z axes (the plane
            orthogonal to the grip force, as the ground truth) and the torsion is about
            tool x, for both bubbles, using ``geometry.gripper``'s camera mount;
            ``"membrane"``: along the plane fitted to the reference membrane (see
            ``perception.shear``).
        overlay_every_n: publish an overlay every n-th frame per bubble (0: never).
        overlay_step_px: spacing of the flow arrows drawn on the overlay.
        overlay_arrow_gain: length of the mean-shear arrow per pixel of shear.
    """

    shear_frame: str = "tool"
    overlay_every_n: int = 1
    overlay_step_px: int = 12
    overlay_arrow_gain: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.shear_frame not in ("tool", "membrane"):
            raise ValueError(
                f"`shear_frame` must be 'tool' or 'membrane', got {self.shear_frame!r}"
            )
        if self.overlay_every_n < 0:
            raise ValueError(f"`overlay_every_n` must be >= 0, got {self.overlay_every_n!r}")
        if self.overlay_step_px < 2:
            raise ValueError(f"`overlay_step_px` must be >= 2, got {self.overlay_step_px!r}")
        if not self.overlay_arrow_gain > 0:
            raise ValueError(f"`overlay_arrow_gain` must be > 0, got {self.overlay_arrow_gain!r}")


@dataclass(frozen=True, kw_only=True)
class FarnebackTrackerParams(ShearTrackerParams):
    """Parameters of ``shear_tracker.farneback`` (``method`` must stay ``"farneback"``)."""

    method: str = "farneback"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.method != "farneback":
            raise ValueError(f"`method` must be 'farneback' for this node, got {self.method!r}")


@dataclass(frozen=True, kw_only=True)
class DisTrackerParams(ShearTrackerParams):
    """Parameters of ``shear_tracker.dis`` (``method`` must stay ``"dis"``)."""

    method: str = "dis"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.method != "dis":
            raise ValueError(f"`method` must be 'dis' for this node, got {self.method!r}")


class _ShearTrackerNode(Node):
    inputs = {"left": ToFImage, "right": ToFImage, "grasp": GraspState, "reset": ShearReset}
    outputs = {"shear": ShearEstimate, "overlay": OverlayImage}
    optional_inputs = frozenset({"left", "right", "reset"})

    def setup(self) -> None:
        self.trackers = {sensor: ShearTracker(self.params) for sensor in SENSORS}
        self.stable = False
        self.stable_since_nanos = 0
        self.want_reference = {sensor: False for sensor in SENSORS}
        self.frames = {sensor: 0 for sensor in SENSORS}
        self.warned_no_ir: set[str] = set()

    def on_grasp(self, msg: GraspState) -> None:
        became_stable = msg.stable and (not self.stable or msg.event == "stable")
        if became_stable:
            self.stable_since_nanos = msg.header.stamp_nanos
            for sensor in SENSORS:
                self.trackers[sensor].drop_reference()
                self.want_reference[sensor] = True
        elif not msg.stable and (self.stable or msg.event == "released"):
            for sensor in SENSORS:
                self.trackers[sensor].drop_reference()
                self.want_reference[sensor] = False
        self.stable = msg.stable

    def on_reset(self, msg: ShearReset) -> None:
        if msg.sensor not in ("", *SENSORS):
            self.io.log.warning("%s: ShearReset for unknown sensor %r", self.name, msg.sensor)
            return
        for sensor in SENSORS if msg.sensor == "" else (msg.sensor,):
            self.trackers[sensor].drop_reference()
            self.want_reference[sensor] = self.stable
        self.stable_since_nanos = min(self.stable_since_nanos, msg.header.stamp_nanos)

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, sensor: str, msg: ToFImage) -> None:
        if msg.ir.size == 0:
            # A camera without the IR channel (the scene's ``ir`` effect off): nothing to track.
            if sensor not in self.warned_no_ir:
                self.io.log.warning("%s: %s frames carry no IR image; skipped", self.name, sensor)
                self.warned_no_ir.add(sensor)
            return
        tracker = self.trackers[sensor]
        shape = tracker.reference_shape
        if shape is not None and shape != msg.ir.shape:
            # The camera changed mode mid-grasp: the old reference cannot be compared.
            self.io.log.warning(
                "%s: %s image is %s, its reference %s; retaking the reference",
                self.name,
                sensor,
                msg.ir.shape,
                shape,
            )
            tracker.drop_reference()
            self.want_reference[sensor] = self.stable
        depth = msg.depth_m if msg.depth_m.shape == msg.ir.shape else None
        if self.want_reference[sensor] and msg.header.stamp_nanos >= self.stable_since_nanos:
            basis = tool_basis_in_sensor(sensor) if self.params.shear_frame == "tool" else None
            tracker.set_reference(msg.ir, depth, PinholeCamera.from_frame(msg), basis)
            self.want_reference[sensor] = False
        every = self.params.overlay_every_n
        want_overlay = every > 0 and self.frames[sensor] % every == 0
        self.frames[sensor] += 1
        result = tracker.update(msg.ir, depth, keep_fields=want_overlay)
        header = Header(stamp_nanos=msg.header.stamp_nanos, frame_id=msg.header.frame_id)
        self.io.publish("shear", _estimate(sensor, header, result))
        if want_overlay:
            image = draw_overlay(
                msg.ir,
                result,
                step_px=self.params.overlay_step_px,
                arrow_gain=self.params.overlay_arrow_gain,
            )
            overlay_header = Header(stamp_nanos=header.stamp_nanos, frame_id=header.frame_id)
            self.io.publish(
                "overlay", OverlayImage(header=overlay_header, sensor=sensor, image=image)
            )


def _estimate(sensor: str, header: Header, result: ShearResult) -> ShearEstimate:
    return ShearEstimate(
        header=header,
        sensor=sensor,
        shear_px=np.asarray(result.shear_px, np.float64),
        magnitude_px=float(result.magnitude_px),
        direction=np.asarray(result.direction, np.float64),
        direction_defined=bool(result.direction_defined),
        shear_mm=np.asarray(result.shear_mm, np.float64),
        torsion_rad=float(result.torsion_rad),
        has_reference=bool(result.has_reference),
    )


@register("shear_tracker.farneback")
class FarnebackShearTracker(_ShearTrackerNode):
    """Shear of each bubble by Farneback flow against its stable-grasp reference (paper)."""

    Params = FarnebackTrackerParams


@register("shear_tracker.dis")
class DisShearTracker(_ShearTrackerNode):
    """Shear of each bubble by DIS flow against its stable-grasp reference."""

    Params = DisTrackerParams
