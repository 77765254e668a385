"""``bubble_camera.sim``: one bubble's simulated internal ToF camera.

Ports:
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``.
    outputs: ``image`` (ToFImage): depth (float32 m, NaN invalid) and IR (uint16), one per
        world state, with its stamp; a channel whose effect is off is a (0, 0) array.
        ``contact_mask`` (MaskImage): the true contact patch, when the scene lists
        ``ground_truth``.

Renders only this camera's effects (``sim.tof.BubbleRenderer``); it loads the scene
the world names in its state. A hardware graph replaces this node with a driver.
"""

from __future__ import annotations

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
