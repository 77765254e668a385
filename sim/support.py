"""Lowering a held object onto a support: the stacking task's mechanics.

A scene's ``support`` section says where a surface (a table, or the top of another
object) lies below the held object and how the arm lowers the gripper onto it; the
task does not know either. Gravity points along ``down_in_tool`` (a unit vector in the
tool frame). From ``descend_from_secs`` the arm lowers the tool at ``speed_m_per_s``
until the jaws are told to open (the arm stops as the gripper lets go) or it has
travelled ``max_travel_m``. At t = 0 the object's lowest point lies ``clearance_m``
above the support.

Once the object touches, the support pushes it back up in the hand by as much as the arm
lowers past contact (``push_m``): the membranes, which stick to the object, shear,
until they slip (``sim.membrane``'s stick limit), exactly what the shear tracker sees.
When the jaws open, the object comes to rest on the support: ``gap_m`` is how far it
fell (0 when it was set down touching), ``tilt_deg`` the angle between its axis and the
vertical at release. It counts as placed when the gap is at most ``placed_max_gap_m``,
else as dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, kw_only=True)
class SupportSpec:
    """A support under the held object and the arm's descent onto it (module docstring)."""

    clearance_m: float = 0.03
    descend_from_secs: float = 2.0
    speed_m_per_s: float = 0.02
    max_travel_m: float = 0.08
    down_in_tool: tuple[float, float, float] = (0.0, -1.0, 0.0)
    placed_max_gap_m: float = 0.002

    def __post_init__(self) -> None:
        for name in ("clearance_m", "descend_from_secs", "placed_max_gap_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"`support.{name}` must be >= 0, got {value!r}")
        for name in ("speed_m_per_s", "max_travel_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"`support.{name}` must be > 0, got {value!r}")
        down = np.asarray(self.down_in_tool, dtype=np.float64)
        if down.shape != (3,) or not abs(np.linalg.norm(down) - 1.0) < 1e-6:
            raise ValueError(
                f"`support.down_in_tool` must be a unit 3-vector, got {self.down_in_tool!r}"
            )


@dataclass(frozen=True)
class Placement:
    """How the object came to rest when the jaws opened (the stacking task's truth)."""

    t_secs: float  # when the jaws were told to open
    touch_secs: float | None  # when the object first touched the support (None: never)
    gap_m: float  # how far it fell onto the support (0: set down touching)
    push_m: float  # how far the arm had lowered past contact (slid in the hand)
    tilt_deg: float  # its axis against the vertical
    placed: bool


class Support:
    """The descent and the support's push on one object (used by ``sim.world.World``)."""

    def __init__(self, spec: SupportSpec, model: object, first_pose: np.ndarray) -> None:
        self.spec = spec
        self.down = np.asarray(spec.down_in_tool, dtype=np.float64)
        self.points = model.sample_surface(3000, np.random.default_rng(0))  # type: ignore[attr-defined]
        # The support's level along `down`, in the tool frame at the start of the descent.
        self.level_m = self.lowest_m(first_pose) + spec.clearance_m
        self.stop_secs: float | None = None
        self.touch_secs: float | None = None
        self.placement: Placement | None = None

    def lowest_m(self, tool_from_object: np.ndarray) -> float:
        """The object's lowest point along ``down`` in the tool frame."""
        rot, trans = tool_from_object[:3, :3], tool_from_object[:3, 3]
        return float(np.max(self.points @ (rot.T @ self.down)) + trans @ self.down)

    def descent_m(self, t_secs: float) -> float:
        """How far the arm has lowered the tool by ``t_secs``."""
        end = t_secs if self.stop_secs is None else min(t_secs, self.stop_secs)
        travel = self.spec.speed_m_per_s * max(0.0, end - self.spec.descend_from_secs)
        return min(travel, self.spec.max_travel_m)

    def apply(self, tool_from_object: np.ndarray, t_secs: float) -> np.ndarray:
        """The scripted pose pushed up by the support (or resting on it once released)."""
        gap = self.level_m - self.descent_m(t_secs) - self.lowest_m(tool_from_object)
        pose = tool_from_object.copy()
        if self.placement is not None:  # released: it lies on the support
            pose[:3, 3] += gap * self.down
            return pose
        if gap < 0:
            if self.touch_secs is None:
                self.touch_secs = t_secs
            pose[:3, 3] += gap * self.down  # pushed up by the overlap
        return pose

    def release(self, t_secs: float, tool_from_object: np.ndarray) -> Placement:
        """The jaws open at ``t_secs``: the arm stops; where the object comes to rest."""
        if self.placement is not None:
            return self.placement
        self.stop_secs = t_secs
        gap = self.level_m - self.descent_m(t_secs) - self.lowest_m(tool_from_object)
        axis = tool_from_object[:3, 2]
        cos = abs(float(axis @ -self.down))
        self.placement = Placement(
            t_secs=t_secs,
            touch_secs=self.touch_secs,
            gap_m=max(gap, 0.0),
            push_m=0.0
            if self.touch_secs is None
            else self.descent_m(t_secs) - self.descent_m(self.touch_secs),
            tilt_deg=math.degrees(math.acos(min(1.0, cos))),
            placed=gap <= self.spec.placed_max_gap_m,
        )
        return self.placement
