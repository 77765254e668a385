"""``world.sim``: the one scene clock and the shared simulated world.

Ports:
    inputs: ``command`` (GripperCommand, optional): commands from a supervisor move
        the simulated jaws (closing on the object makes contact, opening releases it).
    outputs: ``state`` (messages.sim.WorldState): one per scene frame, at the cameras'
        frame rate; the sensor nodes render from it and stamp their messages with its
        stamp. ``ground_truth`` (GroundTruth): the true pose, contact and shear, when
        the scene lists ``ground_truth``.

Only this node integrates anything (the jaws' motion, the contacts' anchors), so no two
processes keep their own copy of the world. When the scene's trajectory ends it asks
the graph to stop, with a one-line summary. A hardware graph drops this node.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from messages.sim import WorldState
from messages.types import GripperCommand, GroundTruth
from runtime.node import Node
from runtime.params import ExistingFile
from runtime.registry import register
from sim import World, ground_truth, load_scene, stamp_of
from sim.effects import resolve
from sim.scene import Scene, SceneError
from sim.wire import apply_command, to_message


@dataclass(frozen=True, kw_only=True)
class WorldParams:
    """``scene``: a scene file; ``effects``/``seed`` override the scene's when given;
    ``rate_scale`` > 1 runs the scene faster than real time."""

    scene: ExistingFile
    effects: tuple[str, ...] = ()
    seed: int = -1
    rate_scale: float = 1.0

    def __post_init__(self) -> None:
        if not self.rate_scale > 0:
            raise ValueError(f"`rate_scale` must be > 0, got {self.rate_scale!r}")
        if self.effects:
            try:
                resolve(self.effects)
            except ValueError as err:
                raise ValueError(f"`effects`: {err}") from err
        try:
            self.load()
        except SceneError as err:
            raise ValueError(f"`scene`: {err}") from err

    def load(self) -> Scene:
        """The scene with this node's overrides applied."""
        scene = load_scene(self.scene)
        changes: dict[str, object] = {}
        if self.effects:
            changes["effects"] = tuple(self.effects)
        if self.seed >= 0:
            changes["seed"] = self.seed
        try:
            return dataclasses.replace(scene, **changes) if changes else scene
        except ValueError as err:
            raise SceneError(f"{self.scene}: {err}") from err


@register("world.sim")
class WorldNode(Node):
    """Steps the scene's world once per camera frame (see the module docstring)."""

    Params = WorldParams
    inputs = {"command": GripperCommand}
    optional_inputs = frozenset({"command"})
    outputs = {"state": WorldState, "ground_truth": GroundTruth}

    def setup(self) -> None:
        self.scene = self.params.load()
        self.world = World(self.scene)
        self.start_nanos: int | None = None
        self.max_force_n = 0.0
        self.contact_frames = 0
        self.io.add_timer(self.scene.frame_period_secs / self.params.rate_scale, self.tick)

    def on_command(self, msg: GripperCommand) -> None:
        refused = apply_command(self.world, msg)
        if refused:
            self.io.log.warning("%s: ignored gripper command: %s", self.name, refused)

    def tick(self) -> None:
        """Advance one frame and publish it; stop the graph after the last one."""
        if self.world.done:
            return
        if self.start_nanos is None:
            self.start_nanos = self.io.now_nanos()
        snap = self.world.step()
        stamp = stamp_of(snap, self.start_nanos)
        self.max_force_n = max(self.max_force_n, snap.force_n)
        self.contact_frames += any(snap.in_contact.values())
        self.io.publish("state", to_message(snap, self.scene, stamp))
        if "ground_truth" in self.world.effects:
            truth = ground_truth(
                snap, self.world.model.class_label, stamp, noise_seed=self.scene.seed
            )
            self.io.publish("ground_truth", truth)
        if self.world.done:
            contact = (
                f"{self.contact_frames} in contact"
                if self.world.needs_contact
                else "contact not simulated"
            )
            self.io.request_stop(
                f"scene {self.scene.name!r} ended at t={snap.time_secs:.2f} s after"
                f" {snap.frame_index + 1} frames ({contact}, peak grip force"
                f" {self.max_force_n:.1f} N, final width {snap.width_m * 1000:.1f} mm,"
                f" gripper {snap.gripper_state})"
            )
