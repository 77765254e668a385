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
    outputs: ``image`` (ToFImage): a PMD pico flexx's frames through the royale SDK
        (``devices.royale``): depth z in metres with NaN where the SDK's confidence is 0
        or its noise over ``max_noise_m``, the gray (IR) channel as uint16, the camera's
        own intrinsics, stamped with the SDK's frame time.
    ``roypy`` is imported when the node starts; without it setup fails saying what to
    install and where. The use case (frame rate) must be one the camera lists.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass

from devices.royale import MAX_NOISE_M, RoyaleCamera
from messages.base import Header
from messages.errors import DeviceError, NodeError
from messages.sim import WorldState
from messages.types import MaskImage, ToFImage
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


@dataclass(frozen=True, kw_only=True)
class RoyaleParams:
    """``camera_id``: the camera's id ("" when only one is plugged in); ``use_case``: the
    SDK's mode name (frame rate and exposure limit), checked against the camera's own
    list; ``exposure_us``: a fixed exposure (0: the use case's)."""

    sensor: str
    camera_id: str = ""
    use_case: str = "MODE_9_10FPS_1000"
    exposure_us: int = 0
    max_noise_m: float = MAX_NOISE_M

    def __post_init__(self) -> None:
        SensorParams(sensor=self.sensor)
        if not self.use_case:
            raise ValueError("`use_case` must name one of the camera's use cases, got ''")
        if self.exposure_us < 0:
            raise ValueError(f"`exposure_us` must be >= 0, got {self.exposure_us!r}")
        if not self.max_noise_m > 0:
            raise ValueError(f"`max_noise_m` must be > 0, got {self.max_noise_m!r}")


@register("bubble_camera.royale")
class RoyaleBubbleCamera(Node):
    """Publishes a PMD pico flexx's frames (see the module docstring)."""

    Params = RoyaleParams
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
        self.io.log.info("%s: camera %r, use case %s", self.name, self.camera.camera_id, p.use_case)
        self.io.add_timer(0.002, self.tick)

    def teardown(self) -> None:
        self.camera.disconnect()

    def tick(self) -> None:
        """Publish the frames the SDK delivered since the last tick."""
        k = self.camera.intrinsics
        assert k is not None
        while True:
            try:
                frame = self.camera.frames.get_nowait()
            except queue.Empty:
                return
            self.io.publish(
                "image",
                ToFImage(
                    header=Header(
                        stamp_nanos=frame.stamp_nanos, frame_id=f"{self.params.sensor}_sensor"
                    ),
                    sensor=self.params.sensor,
                    depth_m=frame.depth_m,
                    ir=frame.ir,
                    fx_px=k.fx_px,
                    fy_px=k.fy_px,
                    cx_px=k.cx_px,
                    cy_px=k.cy_px,
                ),
            )
