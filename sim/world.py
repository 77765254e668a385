"""The world of one scene: one clock, the object's pose, the jaws, contact, anchors.

:class:`World` is the only place anything is integrated over time (the gripper's
motion, where each contact began). Sensors are pure functions of a
:class:`WorldSnapshot` (``sim.tof``), so several processes can render the same
instant from the one ``world.sim`` node without integrating their own copies.

Each step advances one camera frame: scripted commands due by then are applied (as are
commands given with :meth:`World.command`), the gripper moves, and each bubble's contact
is evaluated on its membrane sample grid (``sim.membrane.contact_mechanics``) when an
effect needs it (``gripper``, ``pressure``, ``shear``, ``ground_truth``). A contact's
anchor (the object's pose when that bubble first touched it) is what shear is measured
against: material sticks to the object from then on, up to the slip limit.

With ``wrench`` each bubble's true contact wrench is integrated over its pressed samples
(``sim.friction``); with ``slip`` the object moves in the hand under the scene's
``load`` against the bubbles' friction (its offset from the scripted pose is
``WorldSnapshot.slide_m``), and a slipping bubble's anchor is dragged along.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry.gripper import SIDES
from sim.friction import BubbleWrench, SlipDynamics, bubble_wrench
from sim.gripper import GripperDynamics
from sim.membrane import ContactState, CulledField, Tension, contact_mechanics
from sim.pressure import gauge_pressure_pa
from sim.scene import Scene
from sim.support import Placement, Support

_CONTACT_EFFECTS = frozenset({"gripper", "pressure", "shear", "ground_truth", "wrench", "slip"})


@dataclass(frozen=True)
class WorldSnapshot:
    """Everything the sensors of one instant need (plus what ground truth reports).

    ``anchors`` and ``shear_in_tool_m`` are keyed by side; an anchor is None while that
    bubble is out of contact. Pressures are gauge pascals. Speed is a magnitude.
    ``membranes_f`` (when a world simulates the membrane) is keyed by side too.
    """

    frame_index: int
    time_secs: float
    tool_from_object: np.ndarray
    width_m: float
    speed_m_per_s: float = 0.0
    force_n: float = 0.0
    gripper_state: str = "idle"
    in_contact: dict[str, bool] = field(default_factory=lambda: {s: False for s in SIDES})
    pressure_pa: dict[str, float] = field(default_factory=lambda: {s: 0.0 for s in SIDES})
    anchors: dict[str, np.ndarray | None] = field(default_factory=lambda: {s: None for s in SIDES})
    shear_in_tool_m: dict[str, np.ndarray] = field(
        default_factory=lambda: {s: np.zeros(2) for s in SIDES}
    )
    # A world that simulates the membrane as a mesh (``sim.mujoco``) gives each bubble's
    # outer surface, (N, 3) in its finger frame F, and the mesh's edge length; the
    # cameras then ray-cast it (``sim.mujoco.render``) instead of the geometric model.
    membranes_f: dict[str, np.ndarray] | None = None
    membrane_spacing_m: float = 0.0
    # With ``wrench``: each bubble's true wrench and enclosed air volume.
    wrench: dict[str, BubbleWrench] = field(default_factory=dict)
    volume_m3: dict[str, float] = field(default_factory=dict)
    # With ``slip``: the object's offset from its scripted pose (tool (y, z)), its
    # velocity, and the external load on it (tool frame, weight and pull).
    slide_m: np.ndarray = field(default_factory=lambda: np.zeros(2))
    slide_velocity_m_per_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    load_n: np.ndarray = field(default_factory=lambda: np.zeros(3))


class World:
    """Steps a scene frame by frame (see the module docstring)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        effects = set(scene.resolved_effects)
        self.effects = effects
        self.geometry = scene.gripper_geometry()
        self.model = scene.object_model()
        self.field = CulledField(self.model.field)
        self.bounds = self.field.bounds
        self.samples = self.geometry.bubble.surface_samples(scene.bubble.sample_spacing_m)
        self.rest_volume_m3 = self.geometry.bubble.volume_m3() + scene.bubble.dead_volume_m3
        self.tension = Tension.of(scene.bubble)
        self.dynamics = GripperDynamics(scene.gripper, speed_limited="gripper" in effects)
        self.needs_contact = bool(effects & _CONTACT_EFFECTS)
        self.tracks_anchors = bool(effects & {"shear", "ground_truth", "wrench"})
        self.friction = "wrench" in effects
        self.slip = SlipDynamics(scene.load, scene.bubble) if "slip" in effects else None
        self._script = sorted(scene.gripper.commands, key=lambda c: c.t_secs)
        self._next_command = 0
        self._anchors: dict[str, np.ndarray | None] = {s: None for s in SIDES}
        self.frame_index = -1
        self.snapshot: WorldSnapshot | None = None
        self.support = (
            Support(scene.support, self.model, scene.tool_from_object(0.0))
            if scene.support is not None
            else None
        )
        self._release_due = False
        self.placed: np.ndarray | None = None  # see place()

    @property
    def done(self) -> bool:
        """True once the last frame of the scene has been produced."""
        return self.frame_index >= self.scene.frame_count - 1

    def command(
        self, command: str, *, width_m: float, speed_m_per_s: float, force_n: float
    ) -> None:
        """A gripper command from outside (a supervisor); applies from the next step."""
        self._note_release(command)
        self.dynamics.command(
            command, width_m=width_m, speed_m_per_s=speed_m_per_s, force_n=force_n
        )

    def place(self, tool_from_object: np.ndarray | None) -> None:
        """Hold the object at a pose from the next step on (a hand placing it, as the
        emulated lab of a calibration does); None: back to the scene's trajectory."""
        self.placed = None if tool_from_object is None else np.array(tool_from_object, float)

    def contact(
        self,
        side: str,
        width_m: float,
        tool_from_object: np.ndarray,
        *,
        anchor: np.ndarray | None = None,
    ) -> ContactState:
        """One bubble's contact at a given opening and object pose."""
        return contact_mechanics(
            field=self.field,
            bounds=self.bounds,
            samples=self.samples,
            tool_from_finger=self.geometry.tool_from_finger(side, width_m),
            tool_from_object=tool_from_object,
            anchor_tool_from_object=anchor,
            max_shear_m=self.scene.bubble.max_shear_m,
            keep_samples=self.friction,
        )

    def pressure_pa(self, state: ContactState) -> float:
        """Gauge pressure of a bubble in this contact state (ideal gas, isothermal)."""
        b = self.scene.bubble
        return gauge_pressure_pa(
            state.displaced_volume_m3,
            rest_volume_m3=self.rest_volume_m3,
            inflation_pa=b.inflation_pa,
            ambient_pa=b.ambient_pa,
            compliance_m3_per_pa=b.compliance_m3_per_pa,
        )

    def grip_force_n(self, width_m: float, tool_from_object: np.ndarray) -> float:
        """Normal force between jaws and object at an opening: mean of the two bubbles."""
        return self._force_n({s: self.contact(s, width_m, tool_from_object) for s in SIDES})

    def _force_n(self, states: dict[str, ContactState]) -> float:
        total = 0.0
        for state in states.values():
            if state.in_contact:
                total += self.pressure_pa(state) * state.contact_area_m2
                if self.tension is not None:
                    total += self.tension.force_n(state.contact_area_m2)
        return total / 2.0

    def step(self) -> WorldSnapshot:
        """Advance to the next frame and return its snapshot."""
        self.frame_index += 1
        t = self.frame_index * self.scene.frame_period_secs
        pose = self.scene.tool_from_object(t) if self.placed is None else self.placed
        while (
            self._next_command < len(self._script)
            and self._script[self._next_command].t_secs <= t + 1e-9
        ):
            c = self._script[self._next_command]
            self._note_release(c.command)
            self.dynamics.command(
                c.command, width_m=c.width_m, speed_m_per_s=c.speed_m_per_s, force_n=c.force_n
            )
            self._next_command += 1
        pose = self._supported(pose, t)
        dt = self.scene.frame_period_secs if self.frame_index > 0 else 0.0
        if self.slip is not None:
            pose = self._slide(pose, t - dt, dt)
        # One contact evaluation per side and opening within a step: the gripper's force
        # loop and the snapshot share them. Anchors (for shear) are the previous
        # step's; a contact that starts now gets the current pose, i.e. zero shear.
        memo: dict[float, dict[str, ContactState]] = {}

        def contacts(w: float) -> dict[str, ContactState]:
            if w not in memo:
                anchors = self._anchors if self.tracks_anchors else {}
                memo[w] = {s: self.contact(s, w, pose, anchor=anchors.get(s)) for s in SIDES}
            return memo[w]

        force_at = None
        if "gripper" in self.effects:

            def force_at(w: float) -> float:
                return self._force_n(contacts(w))

        finger = self.dynamics.step(dt, force_at)
        in_contact = {s: False for s in SIDES}
        pressure = {s: 0.0 for s in SIDES}
        shear = {s: np.zeros(2) for s in SIDES}
        wrench: dict[str, BubbleWrench] = {}
        volume: dict[str, float] = {}
        if self.needs_contact:
            for side, state in contacts(finger.width_m).items():
                if self.tracks_anchors:
                    if state.in_contact and self._anchors[side] is None:
                        self._anchors[side] = pose.copy()
                    elif not state.in_contact:
                        self._anchors[side] = None
                in_contact[side] = state.in_contact
                if "pressure" in self.effects:
                    pressure[side] = self.pressure_pa(state)
                shear[side] = state.shear_in_tool_m
                if self.friction:
                    wrench[side], volume[side] = self._wrench(state, pressure[side])
                if self.slip is not None:
                    self.slip.hold(
                        side, state.samples if state.in_contact else None, pressure[side]
                    )
            if self.slip is not None and finger.state == "holding" and all(in_contact.values()):
                self.slip.held = True
        self.snapshot = WorldSnapshot(
            frame_index=self.frame_index,
            time_secs=t,
            tool_from_object=pose,
            width_m=finger.width_m,
            speed_m_per_s=finger.speed_m_per_s,
            force_n=finger.force_n,
            gripper_state=finger.state,
            in_contact=in_contact,
            pressure_pa=pressure,
            anchors={s: (None if a is None else a.copy()) for s, a in self._anchors.items()},
            shear_in_tool_m=shear,
            wrench=wrench,
            volume_m3=volume,
            slide_m=np.zeros(2) if self.slip is None else self.slip.offset_m.copy(),
            slide_velocity_m_per_s=(
                np.zeros(2) if self.slip is None else self.slip.velocity_m_per_s.copy()
            ),
            load_n=np.zeros(3) if self.slip is None else self.scene.load.force_at(t),
        )
        return self.snapshot

    # -- contact forces and slip (``sim.friction``) -------------------------------------

    def _wrench(self, state: ContactState, pressure_pa: float) -> tuple[BubbleWrench, float]:
        """A bubble's true wrench, and its air volume (cap and dead volume, gas law).

        A contact that began this step has no anchor yet in ``state``: no stick shift."""
        b = self.scene.bubble
        air = (
            self.rest_volume_m3
            - state.displaced_volume_m3
            + b.compliance_m3_per_pa * (pressure_pa - b.inflation_pa)
        )
        if not state.in_contact or state.samples is None:
            return BubbleWrench.none(), air
        assert state.samples is not None
        return bubble_wrench(state.samples, pressure_pa, b), air

    def _slide(self, pose: np.ndarray, t_prev: float, dt: float) -> np.ndarray:
        """Integrate the object's slide over the last frame; the pose with it applied."""
        assert self.slip is not None
        if dt > 0 and self.snapshot is not None:
            last = self.snapshot.tool_from_object
            stick = {s: last[1:3, 3] - a[1:3, 3] for s, a in self._anchors.items() if a is not None}
            drag = self.slip.step(t_prev, dt, stick)
            for side, moved in drag.items():
                anchor = self._anchors[side]
                if anchor is not None:
                    anchor[1:3, 3] += moved
        slid = pose.copy()
        slid[1:3, 3] += self.slip.offset_m
        return slid

    # -- a support under the held object (the stacking task, ``sim.support``) ---------

    @property
    def placement(self) -> Placement | None:
        """How the object came to rest on the support once the jaws opened (else None)."""
        return None if self.support is None else self.support.placement

    def _note_release(self, command: str) -> None:
        if self.support is not None and command in ("release", "home"):
            self._release_due = True

    def _supported(self, pose: np.ndarray, t_secs: float) -> np.ndarray:
        if self.support is None:
            return pose
        if self._release_due:
            self._release_due = False
            self.support.release(t_secs, pose)
        return self.support.apply(pose, t_secs)

    def run_to(self, t_secs: float) -> WorldSnapshot:
        """Step until the frame at (or just before) ``t_secs``; returns its snapshot."""
        target = min(
            int(round(t_secs * self.scene.camera.frame_rate_hz)), self.scene.frame_count - 1
        )
        if target < self.frame_index:
            raise ValueError(f"`t_secs` {t_secs} is before the current frame {self.frame_index}")
        while self.frame_index < target or self.snapshot is None:
            self.step()
        assert self.snapshot is not None
        return self.snapshot
