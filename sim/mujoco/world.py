"""A scene stepped in MuJoCo: the second world (``world.mujoco``'s library half).

:class:`MujocoWorld` has the face of ``sim.world.World`` (``step()`` returns a
``WorldSnapshot`` per camera frame, ``command()``, ``done``, ``dynamics``), so the node
and the sensors that read a snapshot work unchanged, and adds what only an engine knows:
the membranes' deformed surfaces (``snapshot.membranes_f``) and the true contact
wrenches, pressures and volumes (:attr:`MujocoWorld.truth`).

Per frame: the scripted commands due are applied, then the physics runs the frame in
steps of about 1 ms; each step the jaws (``sim.gripper.GripperDynamics``, the same
model of the WSG 50 as the simulated world, fed the engine's measured grip force) set
the plates' opening, and the hand holding the object moves to the scene's pose.

What differs from ``world.sim`` on purpose: the object's pose is the engine's (the hand
holds it through a stiff weld, so contact pushes it a little); the grip force is the
mean normal contact force of the two bubbles along the closing axis; the pressure is
the gas law on the shell's enclosed volume; shear truth is the mean tool (y, z)
displacement, since contact began, of the membrane points now in contact. There is no
gravity (the hand carries the object's weight, as in ``world.sim``). Scenes with a
``support`` are refused (no table in this world).

With the ``slip`` effect the scene's ``load`` acts as on ``world.sim`` (``sim.friction``):
the hand carries the object until the jaws hold it with both bubbles, then lets go, and
from then on only the bubbles hold it, against the engine's gravity on the object (its
mass the load's, growing as it is filled) and the load's pull. It slips and falls out
of the grip on MuJoCo's friction (the snapshot's ``slide_m``: its (y, z) offset from
where it was let go, against the scene's trajectory; ``load_n``: the load). Once it
touches neither bubble :data:`DROPPED_M` away, it has fallen out: it is parked there
(``dropped``; this world has no floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.gripper import SIDES
from geometry.se3 import invert
from messages.base import Header
from messages.force import WrenchTruth
from sim.friction import GRAVITY_M_PER_S2, BubbleWrench
from sim.gripper import GripperDynamics
from sim.mujoco.mesh import contact_tolerance_m, vertex_area_vectors
from sim.mujoco.model import ShellSpec
from sim.mujoco.physics import AirSpec, Contacts, GraspPhysics
from sim.scene import Scene
from sim.world import WorldSnapshot

# An object let go that touches neither bubble this far from where it was let go has
# fallen out of the grip: it is parked there (``GraspPhysics.park_object``).
DROPPED_M = 0.03


@dataclass(frozen=True)
class Truth:
    """The engine's ground truth of one frame (tool frame; ``[left, right]``)."""

    contacts: Contacts
    pressure_pa: np.ndarray  # (2,) gauge
    volume_m3: np.ndarray  # (2,) air enclosed by membrane and plate (no dead volume)


class MujocoWorld:
    """Steps a scene in MuJoCo frame by frame (see the module docstring)."""

    def __init__(self, scene: Scene, shell: ShellSpec | None = None) -> None:
        if scene.support is not None:
            raise ValueError(
                f"{scene.path or scene.name}: `support`: the MuJoCo world has no support"
                " surface; use world.sim for stacking scenes"
            )
        self.scene = scene
        self.effects = set(scene.resolved_effects)
        self.model = scene.object_model()
        self.geometry = scene.gripper_geometry()
        period = scene.frame_period_secs
        shell = shell or ShellSpec()
        self.substeps = max(1, math.ceil(period / shell.timestep_secs - 1e-9))
        import dataclasses

        self.shell = dataclasses.replace(shell, timestep_secs=period / self.substeps)
        b = scene.bubble
        # With ``slip`` the scene's load (its mass, fill and pull) acts once the jaws hold.
        self.loaded = "slip" in self.effects
        self.physics = GraspPhysics(
            gripper=self.geometry,
            object_model=self.model,
            width_m=scene.gripper.initial_width_m,
            tool_from_object=scene.tool_from_object(0.0),
            shell=self.shell,
            air=AirSpec(
                inflation_pa=b.inflation_pa,
                ambient_pa=b.ambient_pa,
                dead_volume_m3=b.dead_volume_m3,
            ),
            object_mass_kg=scene.load.mass_kg if self.loaded else None,
        )
        self.physics.inflate()
        self.dynamics = GripperDynamics(scene.gripper, speed_limited="gripper" in self.effects)
        self.needs_contact = True
        self.placement = None
        self._script = sorted(scene.gripper.commands, key=lambda c: c.t_secs)
        self._next_command = 0
        self._anchor_pose: dict[str, np.ndarray | None] = {s: None for s in SIDES}
        self._anchor_points: dict[str, np.ndarray | None] = {s: None for s in SIDES}
        self._grip_force_n = 0.0
        # The object's (y, z) offset from the trajectory when the hand let it go.
        self._let_go_m: np.ndarray | None = None
        self.dropped = False  # let go, then fell out of the grip: parked where it is
        self.frame_index = -1
        self.snapshot: WorldSnapshot | None = None
        self.truth: Truth | None = None

    @property
    def done(self) -> bool:
        return self.frame_index >= self.scene.frame_count - 1

    def command(
        self, command: str, *, width_m: float, speed_m_per_s: float, force_n: float
    ) -> None:
        """A gripper command from outside (a supervisor); applies from the next step."""
        self.dynamics.command(
            command, width_m=width_m, speed_m_per_s=speed_m_per_s, force_n=force_n
        )

    def _force_at(self, width_m: float) -> float:
        return self._grip_force_n

    def step(self) -> WorldSnapshot:
        """Advance to the next frame and return its snapshot."""
        self.frame_index += 1
        period = self.scene.frame_period_secs
        t = self.frame_index * period
        while (
            self._next_command < len(self._script)
            and self._script[self._next_command].t_secs <= t + 1e-9
        ):
            c = self._script[self._next_command]
            self.dynamics.command(
                c.command, width_m=c.width_m, speed_m_per_s=c.speed_m_per_s, force_n=c.force_n
            )
            self._next_command += 1
        ph = self.physics
        force_at = self._force_at if "gripper" in self.effects else None
        if self.frame_index == 0:
            finger = self.dynamics.step(0.0, force_at)
            ph.set_width(finger.width_m)
            ph.step()
        else:
            dt = period / self.substeps
            t0 = t - period
            for k in range(1, self.substeps + 1):
                finger = self.dynamics.step(dt, force_at)
                ph.set_width(finger.width_m)
                self._carry(t0 + k * dt)
                ph.step()
                self._grip_force_n = _grip_force_n(ph.contacts())
        contacts = ph.contacts()
        self._grip_force_n = _grip_force_n(contacts)
        finger.force_n = self._grip_force_n if force_at is not None else 0.0
        pose = ph.tool_from_object()
        if (
            self.loaded
            and self._let_go_m is None
            and finger.state == "holding"
            and min(contacts.count) > 0
        ):
            ph.release_hand()
            self._let_go_m = pose[1:3, 3] - self.scene.tool_from_object(t)[1:3, 3]
        slide = (
            np.zeros(2)
            if self._let_go_m is None
            else pose[1:3, 3] - self.scene.tool_from_object(t)[1:3, 3] - self._let_go_m
        )
        if (
            self._let_go_m is not None
            and not self.dropped
            and max(contacts.count) == 0
            and np.linalg.norm(slide) > DROPPED_M
        ):
            self.dropped = True
            ph.park_object()
        surfaces = {s: ph.surface_f(s) for s in SIDES}
        in_contact = {s: contacts.count[i] > 0 for i, s in enumerate(SIDES)}
        shear = {s: self._shear(s, in_contact[s], pose, surfaces[s]) for s in SIDES}
        self.truth = Truth(
            contacts=contacts,
            pressure_pa=ph.pressure_pa.copy(),
            volume_m3=ph.volume_m3.copy(),
        )
        self.snapshot = WorldSnapshot(
            frame_index=self.frame_index,
            time_secs=t,
            tool_from_object=pose,
            width_m=ph.width_m(),
            speed_m_per_s=finger.speed_m_per_s,
            force_n=finger.force_n,
            gripper_state=finger.state,
            in_contact=in_contact,
            pressure_pa={
                s: float(ph.pressure_pa[i]) if "pressure" in self.effects else 0.0
                for i, s in enumerate(SIDES)
            },
            anchors={s: (None if a is None else a.copy()) for s, a in self._anchor_pose.items()},
            shear_in_tool_m=shear,
            membranes_f=surfaces,
            membrane_spacing_m=self.shell.mesh_spacing_m,
            wrench={
                s: BubbleWrench(
                    contacts.bubble_force_n[i].copy(),
                    contacts.bubble_torque_nm[i].copy(),
                    contacts.slipping_fraction[i],
                    self._contact_area_m2(s, pose, surfaces[s]),
                )
                for i, s in enumerate(SIDES)
            },
            volume_m3={s: float(ph.volume_m3[i]) for i, s in enumerate(SIDES)},
            slide_m=slide,
            load_n=(np.zeros(3) if self._let_go_m is None else self.scene.load.force_at(t)),
        )
        return self.snapshot

    def _carry(self, t_secs: float) -> None:
        """The hand follows the trajectory until it lets go; then the load acts (until
        the object has fallen out of the grip)."""
        if self._let_go_m is None:
            self.physics.set_hand(self.scene.tool_from_object(t_secs))
            return
        if self.dropped:
            return
        load = self.scene.load
        self.physics.set_load(
            load.mass_at(t_secs),
            GRAVITY_M_PER_S2 * np.asarray(load.gravity_in_tool),
            load.pull_at(t_secs),
        )

    def wrench_truth(self, stamp_nanos: int) -> WrenchTruth:
        """The last frame's engine truth as the ``wrench`` message (``source`` mujoco)."""
        truth = self.truth
        if truth is None:
            raise RuntimeError("wrench_truth before the first step")
        c = truth.contacts
        return WrenchTruth(
            header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
            source="mujoco",
            bubble_force_n=c.bubble_force_n,
            bubble_torque_nm=c.bubble_torque_nm,
            object_force_n=c.object_force_n,
            object_torque_nm=c.object_torque_nm,
            pressure_pa=[float(p) for p in truth.pressure_pa],
            volume_m3=[float(v) for v in truth.volume_m3],
        )

    def _shear(
        self, side: str, touching: bool, pose: np.ndarray, surface_f: np.ndarray
    ) -> np.ndarray:
        """Mean tool (y, z) displacement since contact began of the points in contact."""
        tool_from_finger = self.physics.tool_from_finger(side)
        points = surface_f @ tool_from_finger[:3, :3].T + tool_from_finger[:3, 3]
        if not touching:
            self._anchor_pose[side] = None
            self._anchor_points[side] = None
            return np.zeros(2)
        if self._anchor_points[side] is None:
            self._anchor_pose[side] = pose.copy()
            self._anchor_points[side] = points
            return np.zeros(2)
        contact = self.contact_vertices(points, pose)
        if not contact.any():
            return np.zeros(2)
        anchor = self._anchor_points[side]
        assert anchor is not None
        return (points[contact] - anchor[contact])[:, 1:].mean(axis=0)

    def _contact_area_m2(self, side: str, pose: np.ndarray, surface_f: np.ndarray) -> float:
        """The membrane area on the object: a third of each touching triangle per vertex."""
        tool_from_finger = self.physics.tool_from_finger(side)
        points = surface_f @ tool_from_finger[:3, :3].T + tool_from_finger[:3, 3]
        touching = self.contact_vertices(points, pose)
        if not touching.any():
            return 0.0
        area = np.linalg.norm(vertex_area_vectors(surface_f, self.physics.mesh.triangles), axis=1)
        return float(area[touching].sum())

    def contact_vertices(
        self, points_in_tool: np.ndarray, tool_from_object: np.ndarray
    ) -> np.ndarray:
        """Which membrane points lie on the object (within ``contact_tolerance_m``)."""
        object_from_tool = invert(tool_from_object)
        local = points_in_tool @ object_from_tool[:3, :3].T + object_from_tool[:3, 3]
        return self.model.field.value(local) < contact_tolerance_m(self.shell.mesh_spacing_m)


def _grip_force_n(contacts: Contacts) -> float:
    """The grip force: the mean of the two bubbles' normal forces along tool x."""
    return float(np.mean(np.abs(contacts.bubble_force_n[:, 0])))
