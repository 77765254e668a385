"""The gripper: ``gripper.sim`` (the simulated WSG 50) and ``gripper.wsg50`` (the real one).

``gripper.sim``
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``; ``command``
        (GripperCommand, optional). outputs: ``state`` (GripperState): opening, finger
        speed (magnitude), grip force and state (idle | moving | holding | fault), one
        per world state, with its stamp. Commands move the jaws through ``world.sim``'s
        own ``command`` input (the world integrates them, so the cameras and this report
        see one motion); this node checks each against the WSG 50's limits and warns
        about any the real gripper would refuse.

``gripper.wsg50``
    Drives a Schunk WSG 50 over its TCP protocol (``devices.wsg50_client``), or its
    emulator (``world.sim`` with ``wsg50_port``, or ``python -m sim.wsg50_server``).
    inputs: ``command`` (GripperCommand): ``move``/``grasp`` set the force limit then
        start the motion, ``release``, ``stop``, ``home``; a motion command stops a
        running motion first. ``world`` (WorldState, optional, simulated graphs only):
        one state per world state, stamped with its stamp, so the report keeps the
        simulated clock. outputs: ``state`` (GripperState): the opening, speed, force
        and grasping state streamed by the device (auto-update every ``1/rate_hz``),
        published at that rate with the wall clock when there is no world.
    With ``home_on_start`` setup homes the gripper and waits for it (up to
    ``motion_timeout_secs``) before the node reports ready.
    A refused command, a failed motion (no part found, axis blocked) or a lost
    connection is logged with the device's status; the client reconnects with back-off
    and restores the streams. Setup fails, naming the address, if the gripper cannot be
    reached within ``connect_timeout_secs``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated

import msgspec
from msgspec import Meta

from devices.wsg50 import (
    DEFAULT_PORT,
    STATE_NAMES,
    Cmd,
    command_refusal,
)
from devices.wsg50_client import Motion, WSG50Client, float_value, u8_value
from messages.base import Header
from messages.errors import DeviceError, NodeError
from messages.sim import WorldState
from messages.types import GripperCommand, GripperState, GripperStatus
from runtime.node import Node
from runtime.registry import register
from sim import gripper_state
from sim.wire import from_message

_STREAMS = (Cmd.GET_OPENING, Cmd.GET_SPEED, Cmd.GET_FORCE, Cmd.GET_GRASP_STATE)


def _refusal(msg: GripperCommand) -> str:
    return command_refusal(
        msg.command, width_m=msg.width_m, speed_m_per_s=msg.speed_m_per_s, force_n=msg.force_n
    )


@register("gripper.sim")
class SimGripper(Node):
    """Reports the simulated jaws (see the module docstring)."""

    inputs = {"world": WorldState, "command": GripperCommand}
    optional_inputs = frozenset({"command"})
    outputs = {"state": GripperState}

    def on_world(self, msg: WorldState) -> None:
        self.io.publish("state", gripper_state(from_message(msg), msg.header.stamp_nanos))

    def on_command(self, msg: GripperCommand) -> None:
        refusal = _refusal(msg)
        if refusal:
            self.io.log.warning("%s: a WSG 50 would refuse this command: %s", self.name, refusal)


class WSG50Params(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Where the gripper is and how patient to be with it (seconds, hertz)."""

    address: Annotated[str, Meta(description="the gripper's IP address or host name")] = (
        "192.168.1.20"
    )
    port: Annotated[int, Meta(description="its TCP port", ge=1, le=65535)] = DEFAULT_PORT
    home_on_start: Annotated[
        bool, Meta(description="home the gripper in setup, and wait for it, before reporting ready")
    ] = False
    rate_hz: Annotated[
        float,
        Meta(
            description="the device's auto-update rate of its opening, speed, force and grasping state",
            ge=1.0,
            le=500.0,
        ),
    ] = 50.0
    timeout_secs: Annotated[
        float, Meta(description="how long a command's reply is waited for", gt=0)
    ] = 1.0
    connect_timeout_secs: Annotated[
        float, Meta(description="setup fails if the gripper cannot be reached within this", gt=0)
    ] = 10.0
    motion_timeout_secs: Annotated[
        float, Meta(description="the longest a motion (or homing) may take", gt=0)
    ] = 30.0

    def __post_init__(self) -> None:
        if not self.address:
            raise ValueError("`address` must name the gripper's host, got ''")


@register("gripper.wsg50")
class WSG50Gripper(Node):
    """Drives a WSG 50 over TCP (see the module docstring)."""

    Params = WSG50Params
    clocked = True  # reports what the gripper streams, when it streams it
    inputs = {"command": GripperCommand, "world": WorldState}
    optional_inputs = frozenset({"world"})
    outputs = {"state": GripperState}

    def setup(self) -> None:
        p = self.params
        self.client = WSG50Client(
            p.address,
            p.port,
            timeout_secs=p.timeout_secs,
            connect_timeout_secs=p.connect_timeout_secs,
            on_event=lambda event: self.io.log.warning("%s: %s", self.name, event),
        )
        self.motion: Motion | None = None
        self.motion_started = 0.0
        self.has_world = False
        self.last_sample = 0.0
        self.stale_warned = False
        try:
            self.client.connect()
            period_ms = max(1, round(1000.0 / p.rate_hz))
            for command in _STREAMS:
                self.client.stream(command, period_ms)
            if p.home_on_start:
                # Ready only once referenced: a command must not cut the homing short.
                self.client.home().wait(p.motion_timeout_secs)
        except DeviceError as err:
            self.client.disconnect()
            raise NodeError(
                f"{self.name}: {err} (check `address` and `port`, the network, and that"
                " the gripper's TCP interface is enabled)"
            ) from err
        self.io.log.info("%s: connected to %s", self.name, self.client.where)
        self.io.add_timer(1.0 / p.rate_hz, self.tick)

    def teardown(self) -> None:
        self.client.disconnect()

    def on_command(self, msg: GripperCommand) -> None:
        refusal = _refusal(msg)
        if refusal:
            self.io.log.error("%s: refused: %s", self.name, refusal)
            return
        try:
            if msg.command == "stop":
                self.client.stop()
                return
            self._stop_running_motion()
            if msg.command in ("move", "grasp"):
                self.client.set_force_limit(msg.force_n)
            if msg.command == "home":
                self._start(self.client.home)
            elif msg.command == "move":
                self._start(self.client.move, msg.width_m, msg.speed_m_per_s)
            elif msg.command == "grasp":
                self._start(self.client.grasp, msg.width_m, msg.speed_m_per_s)
            else:
                self._start(self.client.release, msg.width_m, msg.speed_m_per_s)
        except DeviceError as err:
            self.io.log.error("%s: %s failed: %s", self.name, msg.command, err)

    def on_world(self, msg: WorldState) -> None:
        self.has_world = True
        self._publish(msg.header.stamp_nanos)

    def tick(self) -> None:
        """Report a finished motion, warn about silence, publish (without a world)."""
        self._check_motion()
        if not self.has_world:
            self._publish(self.io.now_nanos())

    def _start(self, start: Callable[..., Motion], *args: float) -> None:
        self.motion = start(*args)
        self.motion_started = time.monotonic()

    def _stop_running_motion(self) -> None:
        if self.motion is None or self.motion.done:
            return
        self.client.stop()
        try:
            self.motion.wait(self.params.timeout_secs)
        except DeviceError as err:  # E_CMD_ABORTED: what stopping it means
            self.io.log.info("%s: %s", self.name, err)
        self.motion = None

    def _check_motion(self) -> None:
        motion = self.motion
        if motion is None:
            return
        if motion.done:
            self.motion = None
            try:
                status = motion.wait(0.0)
                self.io.log.info(
                    "%s: %s done: %s", self.name, Cmd(motion.command).name, status.name
                )
            except DeviceError as err:
                self.io.log.warning("%s: %s", self.name, err)
        elif time.monotonic() - self.motion_started > self.params.motion_timeout_secs:
            self.io.log.warning(
                "%s: %s has not finished after %g s; stopping it",
                self.name,
                Cmd(motion.command).name,
                self.params.motion_timeout_secs,
            )
            try:
                self._stop_running_motion()
            except DeviceError as err:
                self.io.log.error("%s: stop failed: %s", self.name, err)

    def _publish(self, stamp_nanos: int) -> None:
        latest = self.client.latest(Cmd.GET_OPENING)
        if latest is None:
            return
        now = time.monotonic()
        age = now - latest[1]
        if age > max(5.0 / self.params.rate_hz, 0.5):
            if not self.stale_warned:
                self.io.log.warning(
                    "%s: no state from %s for %.1f s", self.name, self.client.where, age
                )
                self.stale_warned = True
            return
        self.stale_warned = False
        if latest[1] == self.last_sample and not self.has_world:
            return  # nothing new since the last report
        self.last_sample = latest[1]
        width_mm = float_value(latest, Cmd.GET_OPENING) or 0.0
        speed_mm = float_value(self.client.latest(Cmd.GET_SPEED), Cmd.GET_SPEED) or 0.0
        force = float_value(self.client.latest(Cmd.GET_FORCE), Cmd.GET_FORCE) or 0.0
        grasp = u8_value(self.client.latest(Cmd.GET_GRASP_STATE))
        state: GripperStatus = STATE_NAMES.get(grasp, "fault") if grasp is not None else "idle"
        self.io.publish(
            "state",
            GripperState(
                header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
                width_m=width_mm / 1e3,
                speed_m_per_s=abs(speed_mm) / 1e3,
                force_n=force,
                state=state,
            ),
        )
