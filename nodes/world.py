"""``world.sim`` and ``world.mujoco``: the one scene clock and the shared world.

Ports:
    inputs: ``command`` (GripperCommand, optional): commands from a supervisor move
        the simulated jaws (closing on the object makes contact, opening releases it).
        With ``wsg50_port`` the jaws are a WSG 50 emulator instead (``sim.wsg50_server``,
        served from this process): they take commands over the WSG 50 TCP protocol
        only, from ``gripper.wsg50``, and this input is ignored with a warning. The
        world steps the emulated jaws with its contact model, so contact, pressure and
        images follow what the driver commanded.
    outputs: ``state`` (messages.sim.WorldState): one per scene frame, at the cameras'
        frame rate; the sensor nodes render from it and stamp their messages with its
        stamp. ``ground_truth`` (GroundTruth): the true pose, contact and shear, when
        the scene lists ``ground_truth``. ``placement`` (messages.sim.PlacementTruth: placed
        or dropped, the gap it fell, how far the arm pushed past contact, its tilt):
        once, when the jaws open over a scene's ``support`` (``sim.support``): the
        stacking task's truth. ``wrench`` (WrenchTruth, source ``sim``): each bubble's
        true contact wrench, when the scene lists ``wrench``.

With ``rig_feed`` (a ZeroMQ endpoint) the world also publishes each state there for the
emulated devices of an emulated rig (``sim.emulated_rig``: the camera and pressure
emulators inside the hardware graph's own driver nodes). Served jaws move in real time
from setup on (a gripper homes before the graph starts), then with the world's steps.

Only this node integrates anything (the jaws' motion, the contacts' anchors), so no two
processes keep their own copy of the world. When the scene's trajectory ends it asks
the graph to stop, with a one-line summary. A hardware graph drops this node.

``world.mujoco`` (``--swap world=world.mujoco``) runs the same scene in MuJoCo
(``sim.mujoco``, docs/mujoco.md): the same inputs and outputs (each ``state`` also
carries both membranes' deformed surfaces, which the camera nodes ray-cast); its
``wrench`` (messages.force.WrenchTruth, ``source`` ``mujoco``) comes every frame, whatever
the scene's effects: the engine's contact wrenches on each bubble and on the object,
each bubble's gauge pressure and the air volume between membrane and plate. Params as ``world.sim``'s plus ``mesh_spacing_m``
(the membrane mesh's edge length). It publishes as fast as the physics runs (several
CPU seconds per simulated second): every message keeps the scene time of its frame, so
the graph downstream gives the answers it gives on ``world.sim`` in real time, only
later. Scenes with a ``support`` are refused when the graph is checked.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from typing import Annotated, Any

import msgspec
import zmq
from msgspec import Meta

from messages.base import Header
from messages.codec import encode
from messages.errors import NodeError
from messages.force import WrenchTruth
from messages.sim import PlacementTruth, WorldState
from messages.types import GripperCommand, GroundTruth
from runtime.node import Node
from runtime.params import ExistingFile
from runtime.registry import register
from sim import World, WorldSnapshot, ground_truth, load_scene, stamp_of, wrench_truth
from sim.effects import resolve
from sim.scene import Scene, SceneError
from sim.wire import apply_command, to_message
from sim.wsg50_server import WSG50Server, step_in_real_time


class WorldParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``scene``: a scene file; ``effects``/``seed`` override the scene's when given;
    ``rate_scale`` > 1 runs the scene faster than real time; ``wsg50_port`` >= 0 serves
    the jaws over the WSG 50 protocol on ``wsg50_host`` (0: a free port, logged)."""

    scene: Annotated[ExistingFile, Meta(description="a scene file (scenes/)")]
    effects: Annotated[
        tuple[str, ...], Meta(description="the scene's effects, replaced when given (sim.effects)")
    ] = ()
    seed: Annotated[int, Meta(description="the scene's seed, replaced when >= 0")] = -1
    rate_scale: Annotated[
        float, Meta(description="above 1, the scene runs faster than real time", gt=0)
    ] = 1.0
    wsg50_port: Annotated[
        int,
        Meta(
            description=">= 0: serve the jaws over the WSG 50 protocol on this port (0: a free one, logged); -1: not",
            ge=-1,
            le=65535,
        ),
    ] = -1
    wsg50_host: Annotated[str, Meta(description="where the WSG 50 protocol is served")] = (
        "127.0.0.1"
    )
    rig_feed: Annotated[
        str,
        Meta(
            description="a ZeroMQ endpoint the world also publishes each state on, for an emulated rig's devices ('' for none)"
        ),
    ] = ""

    def __post_init__(self) -> None:
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
        changes: dict[str, Any] = {}
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
    clocked = True  # one step per frame period, whatever it hears
    inputs = {"command": GripperCommand}
    optional_inputs = frozenset({"command"})
    outputs = {
        "state": WorldState,
        "ground_truth": GroundTruth,
        "placement": PlacementTruth,
        "wrench": WrenchTruth,
    }

    def make_world(self, scene: Scene) -> World:
        return World(scene)

    def setup(self) -> None:
        self.scene = self.params.load()
        self.placement_sent = False
        self.world = self.make_world(self.scene)
        self.start_nanos: int | None = None
        self.max_force_n = 0.0
        self.contact_frames = 0
        self.server: WSG50Server | None = None
        self.ignored_commands = 0
        if self.params.wsg50_port >= 0:
            host, port = self.params.wsg50_host, self.params.wsg50_port
            try:
                self.server = WSG50Server(self.world.dynamics, host=host, port=port).start()
            except OSError as err:
                raise NodeError(
                    f"{self.name}: cannot serve the WSG 50 protocol on {host}:{port}: {err}"
                ) from err
            self.io.log.info("%s: WSG 50 emulator listening on %s", self.name, self.server.address)
            # Until the first step the jaws move in real time on their own (free of the
            # object, which the scene has not moved yet): a driver homing in its setup
            # sees its motion end before the graph starts.
            self.prestart = threading.Event()
            self.prestart_thread = threading.Thread(
                target=step_in_real_time,
                args=(self.server, lambda width_m: 0.0),
                kwargs={"period_secs": self.scene.frame_period_secs, "stop": self.prestart},
                daemon=True,
            )
            self.prestart_thread.start()
        self.feed: zmq.Socket[bytes] | None = None
        self.gripper_faults: list[Any] = []  # sim.emulated_rig.Fault
        if self.params.rig_feed:
            from sim.emulated_rig import SESSION_ENV, session

            if os.environ.get(SESSION_ENV):
                faults = session().rig.faults
                self.gripper_faults = [f for f in faults if f.device == "gripper"]
            self.feed = zmq.Context.instance().socket(zmq.PUB)
            self.feed.setsockopt(zmq.LINGER, 0)
            try:
                self.feed.bind(self.params.rig_feed)
            except zmq.ZMQError as err:
                raise NodeError(
                    f"{self.name}: cannot bind the rig feed {self.params.rig_feed}: {err}"
                ) from err
        self.io.add_timer(self.scene.frame_period_secs / self.params.rate_scale, self.tick)

    def teardown(self) -> None:
        if self.server is not None:
            self.prestart.set()
            self.server.close()
        if self.feed is not None:
            self.feed.close(0)

    def on_command(self, msg: GripperCommand) -> None:
        if self.server is not None:
            # The jaws answer to the WSG 50 protocol only: a command that bypassed the
            # driver would make the emulated gripper move without its client knowing.
            if not self.ignored_commands:
                self.io.log.warning(
                    "%s: ignoring the command input: the jaws take commands over the WSG 50"
                    " protocol on %s",
                    self.name,
                    self.server.address,
                )
            self.ignored_commands += 1
            return
        refused = apply_command(self.world, msg)
        if refused:
            self.io.log.warning("%s: ignored gripper command: %s", self.name, refused)

    def tick(self) -> None:
        """Advance one frame and publish it; stop the graph after the last one."""
        if self.world.done:
            return
        if self.start_nanos is None:
            self.start_nanos = self.io.now_nanos()
            if self.server is not None:
                self.prestart.set()
                self.prestart_thread.join()
        snap = self.server.stepped(self.world.step) if self.server else self.world.step()
        self._drop_gripper(snap.time_secs)
        stamp = stamp_of(snap, self.start_nanos)
        self.max_force_n = max(self.max_force_n, snap.force_n)
        self.contact_frames += any(snap.in_contact.values())
        state = to_message(snap, self.scene, stamp)
        self.io.publish("state", state)
        if self.feed is not None:
            self.feed.send_multipart(encode("rig/state", state), copy=False)
        if "ground_truth" in self.world.effects:
            truth = ground_truth(
                snap, self.world.model.class_label, stamp, noise_seed=self.scene.seed
            )
            self.io.publish("ground_truth", truth)
        self.publish_wrench(snap, stamp)
        self._publish_placement(stamp)
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

    def publish_wrench(self, snap: WorldSnapshot, stamp: int) -> None:
        """The true contact wrenches, when the scene lists ``wrench``."""
        if "wrench" in self.world.effects:
            self.io.publish("wrench", wrench_truth(snap, stamp))

    def _drop_gripper(self, t_secs: float) -> None:
        """An emulated rig's scripted fault: the WSG 50 drops its clients' connections."""
        due = [f for f in self.gripper_faults if f.at_secs <= t_secs]
        if due and self.server is not None:
            self.gripper_faults = [f for f in self.gripper_faults if f not in due]
            dropped = self.server.drop_clients()
            self.io.log.warning(
                "%s: emulated fault: the WSG 50 dropped %d connection(s) at t=%.2f s",
                self.name,
                dropped,
                t_secs,
            )

    def _publish_placement(self, stamp: int) -> None:
        """The support's verdict, once, when the jaws open over it (``sim.support``)."""
        placement = self.world.placement
        if placement is None or self.placement_sent:
            return
        self.placement_sent = True
        self.io.publish(
            "placement",
            PlacementTruth(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                placed=placement.placed,
                t_secs=placement.t_secs,
                touch_secs=placement.touch_secs,
                gap_m=placement.gap_m,
                push_m=placement.push_m,
                tilt_deg=placement.tilt_deg,
            ),
        )


class MujocoWorldParams(WorldParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``world.sim``'s parameters plus ``mesh_spacing_m``: the membrane mesh's edge length
    (8 mm: 169 vertices a bubble, about 7 CPU s per simulated second; 3 mm: 1,100)."""

    mesh_spacing_m: Annotated[float, Meta(ge=0.003, le=0.02)] = 0.008

    def __post_init__(self) -> None:
        super().__post_init__()
        from sim.mujoco.model import ShellSpec

        ShellSpec(mesh_spacing_m=self.mesh_spacing_m)
        if self.load().support is not None:
            raise ValueError(f"`scene`: {self.scene}: world.mujoco has no support surface")


@register("world.mujoco")
class MujocoWorldNode(WorldNode):
    """The scene in MuJoCo (see the module docstring)."""

    Params = MujocoWorldParams

    def make_world(self, scene: Scene) -> World:
        from sim.mujoco.model import ShellSpec
        from sim.mujoco.world import MujocoWorld

        self.io.log.info("%s: building and inflating the MuJoCo bubbles", self.name)
        return MujocoWorld(scene, ShellSpec(mesh_spacing_m=self.params.mesh_spacing_m))  # type: ignore[return-value]

    def publish_wrench(self, snap: WorldSnapshot, stamp: int) -> None:
        """The engine's contact wrenches, pressures and volumes, every frame."""
        self.io.publish("wrench", self.world.wrench_truth(stamp))  # type: ignore[attr-defined]
