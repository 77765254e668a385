"""The MJCF of a grasp: two pressurised shell bubbles on sliding plates, and an object.

The MuJoCo world frame is the tool frame T (``geometry.gripper``). Each finger is a body
on a slide joint along its plate normal (F x), driven by a stiff position servo; its
membrane is a ``flexcomp`` (dim 2, Saint Venant-Kirchhoff shell, ``sim.mujoco.mesh``)
whose rim vertices are pinned to the finger. The object is a free body built from the
primitives of its ``geometry.objects`` field (cylinders, capsules, boxes; a frustum is a
convex mesh), held by a weld to a mocap body that follows the scene's trajectory (the
hand that holds it), or free (``hand=False``) so only the bubbles hold it.

MuJoCo 4.0 specifics met here: flex elasticity needs ``integrator="discrete"``; vertex
damping is the elasticity ``damping`` (joints of flex vertices take none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.fields import Box, CappedCylinder, Capsule, Frustum, Transformed, Union
from geometry.gripper import SIDES, GripperGeometry
from geometry.se3 import quat_from_matrix
from sim.mujoco.mesh import CapMesh

# Contact groups: membranes touch the object only (not each other, not themselves).
_FLEX_BITS = 'contype="2" conaffinity="1"'
_OBJECT_BITS = 'contype="1" conaffinity="2"'


@dataclass(frozen=True, kw_only=True)
class ShellSpec:
    """The latex shell and its numerics.

    ``young_pa``, ``poisson`` and ``thickness_m``: latex (docs/mujoco.md sources them);
    ``mass_kg`` is the membrane's real mass and ``mass_scale`` how much heavier the model
    makes it (explicit air forces on a 3 g shell diverge at a 1 ms step otherwise;
    gravity is compensated on its vertices, so only steady states are physical);
    ``radius_m`` the flex's collision radius (the contact surface is the mid-surface
    offset by it); ``damping_s`` the elasticity's Rayleigh damping.
    ``contact_timeconst_s`` and ``contact_solimp``: the latex-object contact's softness
    (MuJoCo's ``solref`` time constant and ``solimp``), stiff so the membrane does not
    sink into the object (MuJoCo's defaults let it sink about 0.9 mm under 4 kPa); the
    flex's contact has priority, so these are used as they are, not averaged with the
    object geoms' defaults. The time constant is clamped by MuJoCo to twice the step.
    """

    mesh_spacing_m: float = 0.008
    young_pa: float = 1.0e6
    poisson: float = 0.45
    thickness_m: float = 0.00035
    mass_kg: float = 0.003
    mass_scale: float = 50.0
    radius_m: float = 0.001
    damping_s: float = 0.02
    friction: float = 1.0
    timestep_secs: float = 0.001
    tolerance: float = 1e-5
    impratio: float = 10.0
    contact_timeconst_s: float = 0.002
    contact_solimp: tuple[float, float, float] = (0.99, 0.99, 0.001)

    def __post_init__(self) -> None:
        for name in (
            "mesh_spacing_m",
            "young_pa",
            "thickness_m",
            "mass_kg",
            "mass_scale",
            "radius_m",
            "friction",
            "timestep_secs",
            "tolerance",
            "impratio",
            "contact_timeconst_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be > 0, got {value!r}")
        if not 0.0 <= self.poisson < 0.5:
            raise ValueError(f"`poisson` must be in [0, 0.5), got {self.poisson!r}")
        dmin, dmax, width = self.contact_solimp
        if not (0.0 < dmin < 1.0 and 0.0 < dmax < 1.0 and width > 0.0):
            raise ValueError(
                f"`contact_solimp` must be (dmin, dmax, width) with 0 < d < 1 and width > 0,"
                f" got {self.contact_solimp!r}"
            )
        if not (math.isfinite(self.damping_s) and self.damping_s >= 0):
            raise ValueError(f"`damping_s` must be >= 0, got {self.damping_s!r}")


# Typical masses of the objects (kg): a stoneware mug, a full 0.5 l bottle, a full
# square bottle, a glass. The model's inertia is scaled to them.
OBJECT_MASS_KG = {"mug": 0.35, "pet_bottle": 0.5, "square_bottle": 0.6, "wine_glass": 0.2}


def _fmt(values: np.ndarray | list[float] | tuple[float, ...]) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def _pose_attrs(pose: np.ndarray) -> str:
    return f'pos="{_fmt(pose[:3, 3])}" quat="{_fmt(quat_from_matrix(pose[:3, :3]))}"'


def object_geoms(field: object) -> tuple[list[str], list[str]]:
    """MJCF geoms (and mesh assets) for an object field from ``geometry.objects``.

    Returns:
        ``(geoms, assets)``: XML elements in the object's frame G.

    Raises:
        ValueError: a field primitive with no MuJoCo counterpart.
    """
    geoms: list[str] = []
    assets: list[str] = []

    def visit(f: object, pose: np.ndarray) -> None:
        if isinstance(f, Union):
            for child in f.children:
                visit(child, pose)
        elif isinstance(f, Transformed):
            visit(f.child, pose @ f.parent_from_child)
        elif isinstance(f, CappedCylinder):
            size = _fmt([f.radius_m, f.height_m / 2])
            geoms.append(
                f'<geom type="cylinder" size="{size}" {_pose_attrs(pose)} {_OBJECT_BITS}/>'
            )
        elif isinstance(f, Capsule):
            size = _fmt([f.radius_m, f.length_m / 2])
            geoms.append(f'<geom type="capsule" size="{size}" {_pose_attrs(pose)} {_OBJECT_BITS}/>')
        elif isinstance(f, Box):
            size = _fmt(f.half_m)
            geoms.append(f'<geom type="box" size="{size}" {_pose_attrs(pose)} {_OBJECT_BITS}/>')
        elif isinstance(f, Frustum):
            name = f"frustum{len(assets)}"
            phi = np.linspace(0, 2 * np.pi, 32, endpoint=False)
            rings = [
                np.stack([r * np.cos(phi), r * np.sin(phi), np.full_like(phi, z)], axis=1)
                for r, z in ((f.radius_bottom_m, -f.height_m / 2), (f.radius_top_m, f.height_m / 2))
            ]
            assets.append(f'<mesh name="{name}" vertex="{_fmt(np.concatenate(rings))}"/>')
            geoms.append(f'<geom type="mesh" mesh="{name}" {_pose_attrs(pose)} {_OBJECT_BITS}/>')
        else:
            raise ValueError(f"no MuJoCo geometry for a {type(f).__name__} field")

    visit(field, np.eye(4))
    return geoms, assets


def _flexcomp(side: str, mesh: CapMesh, shell: ShellSpec) -> str:
    return f"""
      <flexcomp name="{side}_membrane" type="direct" dim="2" radius="{shell.radius_m:.9g}"
                point="{_fmt(mesh.rest_m)}" element="{" ".join(map(str, mesh.triangles.ravel()))}"
                mass="{shell.mass_kg * shell.mass_scale:.9g}" rgba="0.9 0.6 0.4 0.8">
        <contact {_FLEX_BITS} condim="3" selfcollide="none" priority="1"
                 friction="{shell.friction:.9g}" solref="{shell.contact_timeconst_s:.9g} 1"
                 solimp="{_fmt(shell.contact_solimp)}"/>
        <elasticity young="{shell.young_pa:.9g}" poisson="{shell.poisson:.9g}"
                    thickness="{shell.thickness_m:.9g}" damping="{shell.damping_s:.9g}"
                    elastic2d="both"/>
      </flexcomp>"""


def grasp_mjcf(
    *,
    gripper: GripperGeometry,
    mesh: CapMesh,
    shell: ShellSpec,
    object_field: object,
    width_m: float,
    tool_from_object: np.ndarray,
    hand: bool = True,
    gravity_m_per_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> str:
    """The whole model as an MJCF string (see the module docstring).

    The fingers start at opening ``width_m``; their slide joints' zero is that opening
    (positive: closing). The object starts at ``tool_from_object``.
    """
    geoms, assets = object_geoms(object_field)
    fingers = []
    for side in SIDES:
        pose = gripper.tool_from_finger(side, width_m)
        fingers.append(
            f"""
    <body name="{side}_finger" {_pose_attrs(pose)}>
      {_flexcomp(side, mesh, shell)}
    </body>"""
        )
    weld = (
        '<equality><weld body1="object" body2="hand" solref="0.01 1"/></equality>' if hand else ""
    )
    mocap = f'<body name="hand" mocap="true" {_pose_attrs(tool_from_object)}/>' if hand else ""
    return f"""<mujoco model="softbubble_grasp">
  <compiler autolimits="true"/>
  <option timestep="{shell.timestep_secs:.9g}" integrator="discrete" solver="Newton"
          tolerance="{shell.tolerance:.9g}" impratio="{shell.impratio:.9g}" cone="elliptic"
          gravity="{_fmt(gravity_m_per_s2)}"/>
  <asset>{"".join(assets)}</asset>
  <worldbody>{"".join(fingers)}
    {mocap}
    <body name="object" {_pose_attrs(tool_from_object)}>
      <freejoint name="object_free"/>
      {"".join(geoms)}
    </body>
  </worldbody>
  {weld}
</mujoco>"""
