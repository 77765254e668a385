"""Stepping the MuJoCo grasp: sealed air in each bubble, contact wrenches, vertices.

:class:`GraspPhysics` owns one ``MjModel``/``MjData`` built by ``sim.mujoco.model``. Each
physics step it applies the air's pressure to every free vertex of both shells (the one
piece of physics written here): the bubble's enclosed volume ``V`` (the cap mesh closed
by the plate) gives the absolute pressure by the isothermal gas law ``p (V + V_dead) =
p0 (V_sealed + V_dead)``, and each free vertex is pushed along its area vector by the
gauge pressure (``sim.mujoco.mesh.vertex_area_vectors``). The bubbles are first inflated
at a constant gauge pressure (the pump's valve open), then sealed: the air's amount is
fixed by the shape they settled to.

The shell's reference (stress-free) shape is the rest cap of ``geometry.gripper`` with
its height scaled by ``sim.mujoco.mesh.REFERENCE_HEIGHT_FRACTION``, so that once inflated it bulges to
about the rest cap's 25 mm: latex is stretched by the air on a real bubble too.

Membrane mass is scaled (``ShellSpec.mass_scale``) and its weight compensated
(``gravcomp``): explicit air forces on a 3 g shell diverge at a 1 ms step. Only steady
states are physical; transients are slower than a real membrane's.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from geometry.gripper import SIDES, BubbleGeometry, GripperGeometry
from sim.mujoco.mesh import (
    CapMesh,
    enclosed_volume_m3,
    membrane_mesh,
    vertex_area_vectors,
    vertex_normals,
)
from sim.mujoco.model import OBJECT_MASS_KG, ShellSpec, grasp_mjcf

RIM_MASS_KG = 100.0
# The fastest the plates move (the WSG 50 tops out at 420 mm/s of opening).
PLATE_SPEED_M_PER_S = 0.5


@dataclass(frozen=True)
class Contacts:
    """Contact wrenches of one instant, tool frame, torques about the tool origin.

    ``bubble_force_n[i]`` is the force the object exerts on bubble ``i`` (``[left,
    right]``); ``object_force_n`` the total contact force on the object.
    """

    bubble_force_n: np.ndarray  # (2, 3)
    bubble_torque_nm: np.ndarray  # (2, 3)
    object_force_n: np.ndarray  # (3,)
    object_torque_nm: np.ndarray  # (3,)
    count: tuple[int, int]  # contacts per bubble
    # Share of each bubble's contacts whose friction force is at its cone's limit.
    slipping_fraction: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class AirSpec:
    """The air in each bubble: gauge inflation, ambient, the dead volume of the tube."""

    inflation_pa: float = 1000.0
    ambient_pa: float = 101_325.0
    dead_volume_m3: float = 10e-6


class GraspPhysics:
    """One MuJoCo grasp: two bubbles, their air, an object (see the module docstring).

    Args:
        gripper: plate and bubble geometry (the bubble is the inflated target shape).
        object_model: a ``geometry.objects.ObjectModel``.
        width_m: the opening the fingers start at (the servos' zero).
        tool_from_object: the object's starting pose.
        shell: the membrane's material and numerics.
        air: inflation and dead volume.
        hand: weld the object to a mocap hand that follows :meth:`set_hand`; False
            leaves it free (only the bubbles hold it).
        gravity_m_per_s2: gravity in the tool frame.
        object_mass_kg: the object's mass (default: :data:`OBJECT_MASS_KG`'s).
    """

    def __init__(
        self,
        *,
        gripper: GripperGeometry,
        object_model: object,
        width_m: float,
        tool_from_object: np.ndarray,
        shell: ShellSpec | None = None,
        air: AirSpec | None = None,
        hand: bool = True,
        gravity_m_per_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
        object_mass_kg: float | None = None,
    ) -> None:
        self.shell = shell or ShellSpec()
        self.air = air or AirSpec()
        self.gripper = gripper
        self.mesh: CapMesh = membrane_mesh(gripper.bubble, self.shell.mesh_spacing_m)
        self.width0_m = float(width_m)
        xml = grasp_mjcf(
            gripper=gripper,
            mesh=self.mesh,
            shell=self.shell,
            object_field=object_model.field,  # type: ignore[attr-defined]
            width_m=width_m,
            tool_from_object=tool_from_object,
            hand=hand,
            gravity_m_per_s2=gravity_m_per_s2,
        )
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.hand = hand
        self._object_body = m.body("object").id
        self._hand_mocap = m.body_mocapid[m.body("hand").id] if hand else -1
        self._finger_body = [m.body(f"{s}_finger").id for s in SIDES]
        self._flex_ids = [
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, f"{s}_membrane") for s in SIDES
        ]
        self._vert = [
            slice(int(m.flex_vertadr[f]), int(m.flex_vertadr[f] + m.flex_vertnum[f]))
            for f in self._flex_ids
        ]
        vertbody = m.flex_vertbodyid
        free = ~self.mesh.pinned
        self._free_bodies = [vertbody[s][free] for s in self._vert]
        m.body_gravcomp[np.concatenate(self._free_bodies)] = 1.0
        # The rim is held by the plate: its vertices are driven kinematically (their
        # slide joints set every step), and made heavy so a step's forces barely move
        # them. (Pinning them to a finger body on a joint makes MuJoCo 4.0's flex
        # stiffness solve ill-conditioned and the step diverge once the finger moves.)
        rim_bodies = np.concatenate([vertbody[s][self.mesh.pinned] for s in self._vert])
        m.body_gravcomp[rim_bodies] = 1.0
        m.body_inertia[rim_bodies] *= (RIM_MASS_KG / m.body_mass[rim_bodies])[:, None]
        m.body_mass[rim_bodies] = RIM_MASS_KG
        self._rim_qpos = [
            m.jnt_qposadr[m.body_jntadr[vertbody[s][self.mesh.pinned]]] for s in self._vert
        ]
        self._rim_dof = [
            m.jnt_dofadr[m.body_jntadr[vertbody[s][self.mesh.pinned]]] for s in self._vert
        ]
        self._width_m = float(width_m)
        self._target_width_m = float(width_m)
        # Object mass: the given one, else the table's, the geometry's inertia scaled to it.
        name = getattr(object_model, "name", "")
        mass = object_mass_kg or OBJECT_MASS_KG.get(name, 0.3)
        ob = self._object_body
        scale = mass / m.body_mass[ob]
        m.body_mass[ob] *= scale
        m.body_inertia[ob] *= scale
        self._object_list = np.flatnonzero(m.geom_bodyid == ob)
        self._sealed_pa: float | None = None  # absolute p * V of the sealed air
        self.pressure_pa = np.full(2, self.air.inflation_pa)
        self.volume_m3 = np.zeros(2)
        self.time_secs = 0.0
        mujoco.mj_setConst(m, self.data)
        mujoco.mj_forward(m, self.data)

    # ------------------------------------------------------------------ state

    @property
    def timestep_secs(self) -> float:
        return float(self.model.opt.timestep)

    def width_m(self) -> float:
        """The opening the fingers are at now."""
        return self._width_m

    def tool_from_finger(self, side: str) -> np.ndarray:
        """The plate's frame F now (the rim moves with it; the finger body stays put)."""
        return self.gripper.tool_from_finger(side, self._width_m)

    def tool_from_object(self) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, :3] = self.data.xmat[self._object_body].reshape(3, 3)
        pose[:3, 3] = self.data.xpos[self._object_body]
        return pose

    def mid_surface_f(self, side: str) -> np.ndarray:
        """The shell's vertices (its mid-surface) in that finger's frame F, (N, 3)."""
        pose = self.tool_from_finger(side)
        pts = self.data.flexvert_xpos[self._vert[SIDES.index(side)]]
        return (pts - pose[:3, 3]) @ pose[:3, :3]

    def surface_f(self, side: str) -> np.ndarray:
        """The membrane's outer surface in F: vertices offset outwards by the flex radius
        (where MuJoCo's contacts are), (N, 3)."""
        mid = self.mid_surface_f(side)
        return mid + self.shell.radius_m * vertex_normals(mid, self.mesh.triangles)

    # ------------------------------------------------------------------ stepping

    def set_width(self, width_m: float) -> None:
        """The opening the plates move to during the next step (an ideal position drive)."""
        self._target_width_m = float(width_m)

    def set_hand(self, tool_from_object: np.ndarray) -> None:
        """Where the hand holding the object is (no effect without ``hand``)."""
        if self._hand_mocap < 0:
            return
        from geometry.se3 import quat_from_matrix

        self.data.mocap_pos[self._hand_mocap] = tool_from_object[:3, 3]
        self.data.mocap_quat[self._hand_mocap] = quat_from_matrix(tool_from_object[:3, :3])

    def release_hand(self) -> None:
        """Switch the hand's weld off: from now on only the bubbles (and the load) hold
        the object. No effect without ``hand``."""
        if self.hand:
            self.data.eq_active[:] = 0

    def set_load(self, mass_kg: float, gravity_m_per_s2: np.ndarray, pull_n: np.ndarray) -> None:
        """The object's mass (its inertia scaled with it: a filling), gravity (tool frame;
        the engine's, on the object alone: the membrane's vertices are compensated) and
        an external pull on its centre of mass (tool frame, newtons)."""
        ob = self._object_body
        m = self.model
        if mass_kg != m.body_mass[ob]:
            m.body_inertia[ob] *= mass_kg / m.body_mass[ob]
            m.body_mass[ob] = mass_kg
        m.opt.gravity[:] = gravity_m_per_s2
        self.data.xfrc_applied[ob, :3] = pull_n

    def park_object(self) -> None:
        """Stop the object where it is, with no load and no contact (it fell out of the
        grip: the world has no floor, and an object falling on for seconds reaches
        distances at which the step loses precision and MuJoCo resets the state; the
        membranes springing back would push it about)."""
        ob = self._object_body
        m = self.model
        dof = m.jnt_dofadr[m.body_jntadr[ob]]
        self.data.qvel[dof : dof + 6] = 0.0
        m.opt.gravity[:] = 0.0
        self.data.xfrc_applied[ob] = 0.0
        m.geom_contype[self._object_list] = 0
        m.geom_conaffinity[self._object_list] = 0

    def object_mass_kg(self) -> float:
        return float(self.model.body_mass[self._object_body])

    def inflate(self, secs: float = 0.4) -> None:
        """Inflate both bubbles at the inflation pressure for ``secs``, then seal them."""
        self._sealed_pa = None
        for _ in range(max(1, round(secs / self.timestep_secs))):
            self.step()
        volume = float(np.mean(self.volume_m3))
        a = self.air
        self._sealed_pa = (a.ambient_pa + a.inflation_pa) * (volume + a.dead_volume_m3)
        self._apply_air()

    def step(self) -> None:
        """One physics step with the air's forces of the current shape.

        The plates move towards the set opening at most :data:`PLATE_SPEED_M_PER_S` (a
        jump, e.g. jaws that moved before the first step, is spread over steps).
        """
        dt = self.timestep_secs
        limit = PLATE_SPEED_M_PER_S * dt
        width = self._width_m + float(np.clip(self._target_width_m - self._width_m, -limit, limit))
        closing = 0.5 * (self._width_m - width)  # each plate, along its F x
        d = self.data
        for i in range(2):
            # Rim vertices' joints: F x, y, z displacements from their rest points.
            d.qpos[self._rim_qpos[i]] = 0.5 * (self.width0_m - width)
            d.qpos[self._rim_qpos[i] + 1] = 0.0
            d.qpos[self._rim_qpos[i] + 2] = 0.0
            d.qvel[self._rim_dof[i]] = closing / dt
            d.qvel[self._rim_dof[i] + 1] = 0.0
            d.qvel[self._rim_dof[i] + 2] = 0.0
        self._width_m = width
        self._apply_air()
        mujoco.mj_step(self.model, d)
        self.time_secs += dt

    def _apply_air(self) -> None:
        a = self.air
        for i, side in enumerate(SIDES):
            pose = self.tool_from_finger(side)
            mid = self.mid_surface_f(side)
            volume = enclosed_volume_m3(mid, self.mesh.triangles)
            self.volume_m3[i] = volume
            if self._sealed_pa is None:
                gauge = a.inflation_pa
            else:
                gauge = self._sealed_pa / max(volume + a.dead_volume_m3, 1e-9) - a.ambient_pa
            self.pressure_pa[i] = gauge
            force_f = gauge * vertex_area_vectors(mid, self.mesh.triangles)
            force = force_f[~self.mesh.pinned] @ pose[:3, :3].T
            self.data.xfrc_applied[self._free_bodies[i], :3] = force

    # ------------------------------------------------------------------ contacts

    def contacts(self) -> Contacts:
        """The contact wrenches now (every active contact's force, as ``mj_contactForce``
        gives it: elliptic cones keep it in the contact frame in ``efc_force``)."""
        d = self.data
        n = d.ncon
        bubble_f = np.zeros((2, 3))
        bubble_t = np.zeros((2, 3))
        if n == 0:
            return Contacts(bubble_f, bubble_t, np.zeros(3), np.zeros(3), (0, 0))
        con = d.contact
        adr = np.asarray(con.efc_address[:n])
        geom = np.asarray(con.geom[:n])
        flex = np.asarray(con.flex[:n])
        on_obj = np.isin(geom, self._object_list)
        keep = (adr >= 0) & on_obj.any(axis=1)
        local = np.zeros((n, 3))
        dim = np.asarray(con.dim[:n])
        for j in range(3):
            ok = keep & (dim > j)
            local[ok, j] = d.efc_force[adr[ok] + j]
        frame = np.asarray(con.frame[:n]).reshape(n, 3, 3)
        force = np.einsum("nji,nj->ni", frame, local)  # frame rows are the contact axes
        # Element 2 receives +force along the normal: the object is one of the two.
        sign = np.where(on_obj[:, 1], 1.0, -1.0)[:, None]
        f_obj = np.where(keep[:, None], sign * force, 0.0)
        t_obj = np.cross(np.asarray(con.pos[:n]), f_obj)
        other = np.where(on_obj[:, 1], flex[:, 0], flex[:, 1])
        counts = [0, 0]
        slipping = [0.0, 0.0]
        at_limit = np.hypot(local[:, 1], local[:, 2]) >= 0.95 * self.shell.friction * local[:, 0]
        for i, fid in enumerate(self._flex_ids):
            mine = keep & (other == fid)
            bubble_f[i] = -f_obj[mine].sum(axis=0)
            bubble_t[i] = -t_obj[mine].sum(axis=0)
            counts[i] = int(mine.sum())
            slipping[i] = float((at_limit & mine).sum() / counts[i]) if counts[i] else 0.0
        return Contacts(
            bubble_f,
            bubble_t,
            f_obj.sum(axis=0),
            t_obj.sum(axis=0),
            (counts[0], counts[1]),
            (slipping[0], slipping[1]),
        )


def default_gripper(bubble: BubbleGeometry | None = None) -> GripperGeometry:
    """The gripper geometry with ``bubble`` (or the default one)."""
    return GripperGeometry(bubble=bubble) if bubble is not None else GripperGeometry()
