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
With ``shear_frame: tool`` the frame's ``tool_from_sensor`` gives the tool axes; frames
that do not carry it are refused (with a warning naming the field). The logic, including
when references are taken, is :class:`perception.shear.GraspShear` (no sockets).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from msgspec import Meta

from geometry.camera import PinholeCamera
from messages.base import Header
from messages.shear import ShearReset
from messages.types import (
    GraspState,
    OverlayImage,
    ShearEstimate,
    Side,
    ToFImage,
    pose_is_known,
)
from perception.shear import GraspShear, ShearParams, ShearResult, draw_overlay, tool_basis
from runtime.node import Node
from runtime.registry import register

SENSORS = ("left", "right")


class ShearTrackerParams(ShearParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The flow and mask parameters, plus the frame of ``shear_m`` and the overlay's."""

    shear_frame: Annotated[
        Literal["tool", "membrane"],
        Meta(
            description=(
                '``"tool"``: ``shear_m`` is along the tool\'s y and z axes (the plane '
                "orthogonal to the grip force, as the ground truth) and the torsion is "
                "about tool x, for both bubbles, using the camera mount each frame "
                'carries (``ToFImage.tool_from_sensor``); ``"membrane"``: along the '
                "plane fitted to the reference membrane (see ``perception.shear``)."
            )
        ),
    ] = "tool"
    overlay_every_n: Annotated[
        int, Meta(ge=0, description="publish an overlay every n-th frame per bubble (0: never).")
    ] = 1
    overlay_step_px: Annotated[
        int, Meta(ge=2, description="spacing of the flow arrows drawn on the overlay.")
    ] = 12
    overlay_arrow_gain: Annotated[
        float, Meta(gt=0, description="length of the mean-shear arrow per pixel of shear.")
    ] = 10.0


class FarnebackTrackerParams(
    ShearTrackerParams, frozen=True, kw_only=True, forbid_unknown_fields=True
):
    """Parameters of ``shear_tracker.farneback`` (``method`` must stay ``"farneback"``)."""

    method: Literal["farneback"] = "farneback"


class DisTrackerParams(ShearTrackerParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of ``shear_tracker.dis`` (``method`` must stay ``"dis"``)."""

    method: Literal["dis"] = "dis"


class _ShearTrackerNode(Node):
    inputs = {"left": ToFImage, "right": ToFImage, "grasp": GraspState, "reset": ShearReset}
    outputs = {"shear": ShearEstimate, "overlay": OverlayImage}
    optional_inputs = frozenset({"left", "right", "reset"})

    def setup(self) -> None:
        self.shear = GraspShear(self.params, SENSORS)
        self.frames = dict.fromkeys(SENSORS, 0)
        self.warned: set[tuple[str, str]] = set()

    def _warn_once(self, sensor: str, what: str, text: str) -> None:
        if (sensor, what) not in self.warned:
            self.io.log.warning("%s: %s %s", self.name, sensor, text)
            self.warned.add((sensor, what))

    def on_grasp(self, msg: GraspState) -> None:
        self.shear.grasp(stable=msg.stable, event=msg.event, stamp_nanos=msg.header.stamp_nanos)

    def on_reset(self, msg: ShearReset) -> None:
        try:
            self.shear.reset(msg.sensor, msg.header.stamp_nanos)
        except ValueError as err:
            self.io.log.warning("%s: ShearReset: %s", self.name, err)

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, sensor: Side, msg: ToFImage) -> None:
        if msg.ir.size == 0:
            # A camera without the IR channel (the scene's ``ir`` effect off): nothing to track.
            self._warn_once(sensor, "ir", "frames carry no IR image; skipped")
            return
        basis = None
        if self.params.shear_frame == "tool":
            if not pose_is_known(msg.tool_from_sensor):
                self._warn_once(
                    sensor,
                    "mount",
                    "frames carry no `tool_from_sensor` (the camera mount), which "
                    "shear_frame 'tool' needs; refused (set shear_frame: membrane to use "
                    "the membrane's own plane)",
                )
                return
            basis = tool_basis(msg.tool_from_sensor)
        depth = msg.depth_m if msg.depth_m.shape == msg.ir.shape else None
        every = self.params.overlay_every_n
        want_overlay = every > 0 and self.frames[sensor] % every == 0
        self.frames[sensor] += 1
        result, retaken = self.shear.image(
            sensor,
            msg.ir,
            depth,
            PinholeCamera.from_frame(msg),
            stamp_nanos=msg.header.stamp_nanos,
            basis=basis,
            keep_fields=want_overlay,
        )
        if retaken:
            self.io.log.warning(
                "%s: %s image changed shape to %s; retaking the reference",
                self.name,
                sensor,
                msg.ir.shape,
            )
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


def _estimate(sensor: Side, header: Header, result: ShearResult) -> ShearEstimate:
    return ShearEstimate(
        header=header,
        sensor=sensor,
        shear_px=np.asarray(result.shear_px, np.float64),
        magnitude_px=float(result.magnitude_px),
        direction=np.asarray(result.direction, np.float64),
        direction_defined=bool(result.direction_defined),
        shear_m=np.asarray(result.shear_m, np.float64),
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
