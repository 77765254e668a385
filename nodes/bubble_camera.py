"""One bubble's internal ToF camera: ``bubble_camera.sim`` and ``bubble_camera.royale``.

``bubble_camera.sim``
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``.
    outputs: ``image`` (ToFImage): depth (float32 m, NaN invalid) and IR (uint16), one
        per world state, with its stamp; a channel whose effect is off is a (0, 0) array.
        ``contact_mask`` (MaskImage): the true contact patch, when the scene lists
        ``ground_truth``.
    Renders only this camera's effects (``sim.tof.BubbleRenderer``); it loads the scene
    the world names in its state.

``bubble_camera.royale``
    inputs: ``gripper`` (GripperState, optional): the measured opening, which places
        each frame in the tool frame.
    outputs: ``image`` (ToFImage): a PMD pico flexx's frames through the royale SDK
        (``devices.royale``): depth z in metres with NaN where the SDK's confidence is 0
        or its noise over ``max_noise_m``, the gray (IR) channel as uint16, the camera's
        own intrinsics, stamped with the SDK's frame time, and ``tool_from_sensor``: the
        camera's mount in its finger (the ``calibration`` file's, made for this camera's
        id; the CAD mount without one, said once) at the gripper's opening at the
        frame's stamp (``geometry.mount``). A frame waits up to ``opening_wait_secs``
        for a gripper state stamped at or after it, then takes the newest opening; with
        no gripper state at all it goes out without a pose (said once), and the contact
        patch and shear tracker refuse it.
    ``roypy`` is imported when the node starts; without it setup fails saying what to
    install and where. The use case (frame rate) must be one the camera lists. A camera
    unplugged mid-run (no frame for ``lost_after_secs``) is reported once, naming it,
    and reopened every second until it delivers again.
"""

from __future__ import annotations

import queue
import time
from collections import deque
from collections.abc import Mapping
from typing import Annotated, Literal

import msgspec
import numpy as np
from msgspec import Meta

from devices.royale import MAX_NOISE_M, Frame, RoyaleCamera
from geometry.mount import CAD_MOUNTS, CameraMounts, OpeningHistory
from messages.base import Header
from messages.errors import DeviceError, NodeError
from messages.sim import WorldState
from messages.types import GripperState, MaskImage, ToFImage
from perception.calibration.rigfile import CalibrationError, load_calibration
from runtime.node import Node
from runtime.registry import register
from sim.tof import BubbleRenderer
from sim.wire import SensorParams, from_message, scene_of


@register("bubble_camera.sim")
class SimBubbleCamera(Node):
    """Renders a ``ToFImage`` for every world state (see the module docstring)."""

    Params = SensorParams
    inputs = {"world": WorldState}
    outputs = {"image": ToFImage, "contact_mask": MaskImage}

    def setup(self) -> None:
        self.renderer: BubbleRenderer | None = None

    def on_world(self, msg: WorldState) -> None:
        scene = scene_of(msg)
        if self.renderer is None or self.renderer.scene != scene:
            self.renderer = BubbleRenderer(scene, self.params.sensor)
        frame = self.renderer.render(from_message(msg))
        stamp = msg.header.stamp_nanos
        self.io.publish("image", frame.tof_image(self.renderer.camera, stamp))
        if "ground_truth" in msg.effects:
            self.io.publish("contact_mask", frame.contact_mask(stamp))


class RoyaleParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``camera_id``: the camera's id ("" when only one is plugged in); ``use_case``: the
    SDK's mode name (frame rate and exposure limit), checked against the camera's own
    list; ``exposure_us``: a fixed exposure (0: the use case's); ``calibration``: the
    rig's calibration file ("" : the CAD mount); ``opening_wait_secs``: how long a frame
    waits for the gripper's opening at its stamp; ``lost_after_secs``: silence after
    which the camera counts as unplugged."""

    sensor: Annotated[Literal["left", "right"], Meta(description="which bubble: left or right")]
    camera_id: Annotated[
        str, Meta(description="the camera's id ('' when only one is plugged in)")
    ] = ""
    use_case: Annotated[
        str,
        Meta(
            description="the SDK's mode name (frame rate and exposure limit), checked against the camera's own list"
        ),
    ] = "MODE_9_10FPS_1000"
    exposure_us: Annotated[int, Meta(description="a fixed exposure (0: the use case's)", ge=0)] = 0
    max_noise_m: Annotated[
        float,
        Meta(description="a pixel whose noise the SDK reports above this is invalid (NaN)", gt=0),
    ] = MAX_NOISE_M
    calibration: Annotated[
        str, Meta(description="the rig's calibration file ('': the CAD mount)")
    ] = ""
    opening_wait_secs: Annotated[
        float,
        Meta(description="how long a frame waits for the gripper's opening at its stamp", ge=0),
    ] = 0.1
    lost_after_secs: Annotated[
        float, Meta(description="silence after which the camera counts as unplugged", gt=0)
    ] = 1.0

    def __post_init__(self) -> None:
        if not self.use_case:
            raise ValueError("`use_case` must name one of the camera's use cases, got ''")
        if self.calibration:
            try:
                load_calibration(self.calibration)
            except CalibrationError as err:
                raise ValueError(f"`calibration`: {err}") from err


@register("bubble_camera.royale")
class RoyaleBubbleCamera(Node):
    """Publishes a PMD pico flexx's frames, placed in the tool frame (module docstring)."""

    Params = RoyaleParams
    clocked = True  # publishes what the camera streams, when it streams it
    inputs = {"gripper": GripperState}
    optional_inputs = frozenset({"gripper"})
    outputs = {"image": ToFImage}

    def setup(self) -> None:
        p = self.params
        self.camera = RoyaleCamera(
            p.camera_id, use_case=p.use_case, exposure_us=p.exposure_us, max_noise_m=p.max_noise_m
        )
        try:
            self.camera.connect()
        except DeviceError as err:
            raise NodeError(f"{self.name}: {err}") from err
        self.mounts = CAD_MOUNTS
        if p.calibration:
            try:
                cal = load_calibration(p.calibration).camera(p.sensor, self.camera.camera_id)
            except CalibrationError as err:
                raise NodeError(f"{self.name}: calibration refused: {err}") from err
            self.mounts = CameraMounts({p.sensor: cal.finger_from_sensor})
            where = f"calibrated mount from {p.calibration}"
            self._compare_intrinsics(cal.intrinsics)
        else:
            where = "no calibration file: the CAD camera mount (run `launch.py calibrate`)"
        self.io.log.info(
            "%s: camera %r, use case %s, %s", self.name, self.camera.camera_id, p.use_case, where
        )
        self.openings = OpeningHistory()
        self.pending: deque[tuple[Frame, float]] = deque()
        self.unplaced = 0
        self.last_frame_at: float | None = None  # watched from the first frame on
        self.lost_at: float | None = None
        self.next_try = 0.0
        self.io.add_timer(0.002, self.tick)

    def _compare_intrinsics(self, calibrated: Mapping[str, float]) -> None:
        """Warn when the camera's lens parameters are not those the mount was measured with
        (another lens or camera under the same id): the mount may be off too."""
        k = self.camera.intrinsics
        assert k is not None
        now = {"fx": k.fx_px, "fy": k.fy_px, "cx": k.cx_px, "cy": k.cy_px}
        off = {n: (calibrated[n], v) for n, v in now.items() if abs(calibrated.get(n, v) - v) > 0.5}
        if off:
            self.io.log.warning(
                "%s: the camera's intrinsics differ from the calibration's (%s): recalibrate",
                self.name,
                ", ".join(f"{n} {was:.1f} -> {v:.1f}" for n, (was, v) in off.items()),
            )

    def teardown(self) -> None:
        self.camera.disconnect()

    def on_gripper(self, msg: GripperState) -> None:
        self.openings.add(msg.header.stamp_nanos, msg.width_m)

    def tick(self) -> None:
        """Take the frames the SDK delivered; publish those whose opening is known."""
        now = time.monotonic()
        while True:
            try:
                frame = self.camera.frames.get_nowait()
            except queue.Empty:
                break
            self.pending.append((frame, now))
            self.last_frame_at = now
        if self.lost_at is not None and self.pending:
            self.io.log.warning(
                "%s: camera %r is back after %.1f s",
                self.name,
                self.camera.camera_id,
                now - self.lost_at,
            )
            self.lost_at = None
        self._watch(now)
        newest = self.openings.newest_nanos
        while self.pending:
            frame, arrived = self.pending[0]
            if (newest is None or newest < frame.stamp_nanos) and (
                now - arrived < self.params.opening_wait_secs
            ):
                return
            self.pending.popleft()
            self._publish(frame)

    def _watch(self, now: float) -> None:
        """Report a camera that went silent (unplugged), and reopen it every second."""
        p = self.params
        if self.last_frame_at is None:
            return
        if self.lost_at is None:
            if now - self.last_frame_at < p.lost_after_secs:
                return
            self.lost_at = self.next_try = now
            self.io.log.error(
                "%s: camera %r delivered no frame for %.1f s (unplugged?); reopening it"
                " every second",
                self.name,
                self.camera.camera_id,
                now - self.last_frame_at,
            )
        if now < self.next_try:
            return
        self.next_try = now + 1.0
        self.camera.disconnect()
        try:
            self.camera.connect()
        except DeviceError:
            return  # still gone: reported when it went

    def _publish(self, frame: Frame) -> None:
        p = self.params
        k = self.camera.intrinsics
        assert k is not None
        width = self.openings.width_at(frame.stamp_nanos)
        if width is None:
            pose = np.zeros((4, 4))
            self.unplaced += 1
            if self.unplaced == 1:
                self.io.log.warning(
                    "%s: no gripper state yet: frames go out without `tool_from_sensor`"
                    " (wire `gripper: gripper/state` to place them in the tool frame)",
                    self.name,
                )
        else:
            pose = self.mounts.tool_from_sensor(p.sensor, width)
        self.io.publish(
            "image",
            ToFImage(
                header=Header(stamp_nanos=frame.stamp_nanos, frame_id=f"{p.sensor}_sensor"),
                sensor=p.sensor,
                depth_m=frame.depth_m,
                ir=frame.ir,
                fx_px=k.fx_px,
                fy_px=k.fy_px,
                cx_px=k.cx_px,
                cy_px=k.cy_px,
                tool_from_sensor=pose,
            ),
        )
