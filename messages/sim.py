"""The simulator's shared world state: what ``world.sim`` tells the sensor nodes.

One ``WorldState`` per scene frame; every sensor message of that instant carries its
stamp. Poses are 4x4 float64 ``tool_from_object``; pressures are gauge pascals; lists of
two are ``[left, right]``. A hardware graph has no world and no ``WorldState``.
"""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec
import numpy as np

from messages.base import Array, Header, Message
from messages.types import GripperStatus

_Pose = Annotated[np.ndarray, Array("float64", (4, 4))]
_Vec2 = Annotated[np.ndarray, Array("float64", (2,))]
_Points = Annotated[np.ndarray, Array("float32", (None, 3))]


def _eye() -> np.ndarray:
    return np.eye(4)


def _zeros2() -> np.ndarray:
    return np.zeros(2)


def _no_points() -> np.ndarray:
    return np.zeros((0, 3), np.float32)


class WorldState(Message):
    """The simulated world at one instant (see ``sim.world.WorldSnapshot``).

    ``scene_path``, ``effects`` and ``seed`` let each sensor node load the same scene the
    world runs; ``anchor_*`` is the object's pose when that bubble's contact began
    (identity with ``has_anchor`` false while out of contact); ``shear_*_m`` is the
    true mean membrane shift in the contact, tool (y, z), metres. A world that simulates
    the membrane as a mesh (``world.mujoco``) sends each bubble's outer surface in
    ``membrane_*_m`` (its vertices in that finger's plate frame, metres; the topology is
    ``sim.mujoco.mesh.membrane_mesh`` at ``membrane_spacing_m``) and the cameras ray-cast
    it; empty (0, 3) arrays, spacing 0, from a world without one. ``object_dims_m`` and
    ``object_variant`` are the object the world holds when it is not the scene file's
    (the auto-labeller's variants, ``geometry.variants``; -1: no variant): the sensor
    nodes build that object, not the file's; ``tension_n_per_m`` the membrane's tension
    when the world drew one (``sim.rig.BubbleSpec``; 0: the file's).
    """

    header: Header
    scene_path: str
    effects: list[str]
    seed: int
    frame_index: int
    time_secs: float
    tool_from_object: _Pose
    width_m: float
    speed_m_per_s: float = 0.0
    force_n: float = 0.0
    gripper_state: GripperStatus = "idle"
    in_contact: list[bool] = msgspec.field(default_factory=lambda: [False, False])
    pressure_pa: list[float] = msgspec.field(default_factory=lambda: [0.0, 0.0])
    has_anchor: list[bool] = msgspec.field(default_factory=lambda: [False, False])
    anchor_left: _Pose = msgspec.field(default_factory=_eye)
    anchor_right: _Pose = msgspec.field(default_factory=_eye)
    shear_left_m: _Vec2 = msgspec.field(default_factory=_zeros2)
    shear_right_m: _Vec2 = msgspec.field(default_factory=_zeros2)
    membrane_spacing_m: float = 0.0
    membrane_left_m: _Points = msgspec.field(default_factory=_no_points)
    membrane_right_m: _Points = msgspec.field(default_factory=_no_points)
    object_dims_m: dict[str, float] = msgspec.field(default_factory=dict)
    object_variant: int = -1
    tension_n_per_m: float = 0.0


class PlacementTruth(Message):
    """How a set-down object came to rest when the jaws opened over a scene's support (the
    stacking task's truth, for scoring; ``sim.support``): once per run.

    ``placed`` (resting on the support) or dropped; ``t_secs`` when the jaws were told to
    open and ``touch_secs`` when the object first touched the support (None: never), both
    scene time; ``gap_m`` how far it fell onto the support (0: set down touching),
    ``push_m`` how far the arm had lowered past contact (it slid in the hand), ``tilt_deg``
    its axis against the vertical.
    """

    header: Header
    placed: bool
    t_secs: float
    touch_secs: float | None
    gap_m: float
    push_m: float
    tilt_deg: float

    finite_fields: ClassVar[tuple[str, ...]] = ("t_secs", "gap_m", "push_m", "tilt_deg")
