"""Tangential contact mechanics: the bubbles' true wrench, and slip of the held object.

The membrane model (``sim.membrane``) gives each bubble's pressed samples; this module
adds what the ``wrench`` and ``slip`` effects need (docs/sim.md, docs/force.md):

* Normal traction: the gas pushes every pressed sample with the gauge pressure ``p``
  (a thin membrane transmits its pressure), so a bubble presses the object with
  ``p`` times the patch's area projected on the plate, along the plate's normal.
* Tangential traction: material stuck to the object since the contact's anchor is
  carried along by ``s`` (``sim.membrane.material_shift``); it pulls back with
  ``k g s`` per square metre, ``k`` the centre's stiffness and
  ``g = 1 + edge_stiffening (1 - d / d_max)`` (``d`` the sample's indentation) larger
  towards the patch's edge, where the stretched free membrane pulls too. A sample
  slips once that reaches Coulomb's ``friction * p``, i.e. past the shift
  ``friction * p / (k g)``: the edge slips first, the centre last (partial slip, then
  the whole patch).
* The wrench on a bubble is the sum of its samples' tractions; the torque is about the
  tool frame's origin.
* Slip (the ``slip`` effect, :class:`SlipDynamics`): the object is a mass in the tool's
  (y, z) plane under a ``load`` (gravity on a mass that may grow as it is filled, and a
  pull, from the scene) and the bubbles' tangential forces for a uniform shift. Past
  the whole patch's limit a bubble's anchor is dragged along (the material re-sticks
  further on), and the object slides. A firmer grasp raises ``p`` and the area, hence
  the limit: squeezing harder stops a slide.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.membrane import PatchSamples
from sim.rig import BubbleSpec, nonnegative, positive

GRAVITY_M_PER_S2 = 9.81


@dataclass(frozen=True, kw_only=True)
class PullKeyframe:
    """An external force on the object at ``t_secs`` (tool frame, newtons); linear between."""

    t_secs: float
    force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        nonnegative(self, "t_secs")
        if not all(math.isfinite(v) for v in self.force_n):
            raise ValueError(f"`force_n` must be finite, got {self.force_n!r}")


@dataclass(frozen=True, kw_only=True)
class LoadSpec:
    """What loads the held object (the scene's ``load`` section, used by ``slip``).

    ``mass_kg`` grows by ``fill_kg_per_s`` from ``fill_from_secs`` up to ``max_mass_kg``
    (a glass being filled); ``gravity_in_tool`` is the unit direction of gravity in the
    tool frame; ``pull`` keyframes an external force (a person pulling);
    ``damping_n_s_per_m`` damps the object's motion in the hand (the latex is lossy).
    """

    mass_kg: float = 0.35
    fill_kg_per_s: float = 0.0
    fill_from_secs: float = 0.0
    max_mass_kg: float = 5.0
    gravity_in_tool: tuple[float, float, float] = (0.0, -1.0, 0.0)
    pull: tuple[PullKeyframe, ...] = ()
    damping_n_s_per_m: float = 60.0
    substeps: int = 20

    def __post_init__(self) -> None:
        positive(self, "mass_kg", "max_mass_kg")
        nonnegative(self, "fill_kg_per_s", "fill_from_secs", "damping_n_s_per_m")
        norm = math.sqrt(sum(v * v for v in self.gravity_in_tool))
        if not (math.isfinite(norm) and abs(norm - 1.0) < 1e-6 or norm == 0.0):
            raise ValueError(f"`gravity_in_tool` must be a unit vector (or zero), got {norm:g}")
        if not 1 <= self.substeps <= 1000:
            raise ValueError(f"`substeps` must be in [1, 1000], got {self.substeps!r}")
        times = [k.t_secs for k in self.pull]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"`pull` times must increase, got {times}")

    def mass_at(self, t_secs: float) -> float:
        filled = self.fill_kg_per_s * max(0.0, t_secs - self.fill_from_secs)
        return min(self.mass_kg + filled, max(self.max_mass_kg, self.mass_kg))

    def pull_at(self, t_secs: float) -> np.ndarray:
        if not self.pull:
            return np.zeros(3)
        times = [k.t_secs for k in self.pull]
        forces = np.array([k.force_n for k in self.pull], dtype=np.float64)
        return np.array([np.interp(t_secs, times, forces[:, i]) for i in range(3)])

    def force_at(self, t_secs: float) -> np.ndarray:
        """The external load on the object (weight and pull), tool frame, newtons."""
        weight = self.mass_at(t_secs) * GRAVITY_M_PER_S2 * np.asarray(self.gravity_in_tool)
        return weight + self.pull_at(t_secs)


def stiffening(indentation_m: np.ndarray, edge_stiffening: float) -> np.ndarray:
    """``g`` per sample: 1 at the deepest sample, ``1 + edge_stiffening`` at the rim."""
    deepest = float(indentation_m.max()) if indentation_m.size else 0.0
    if deepest <= 0.0:
        return np.ones_like(indentation_m)
    return 1.0 + edge_stiffening * (1.0 - indentation_m / deepest)


def slip_shift_m(pressure_pa: float, g: np.ndarray, bubble: BubbleSpec) -> np.ndarray:
    """The shift past which each sample slips (also capped at the stick limit)."""
    limit = bubble.friction * max(pressure_pa, 0.0) / (bubble.shear_stiffness_n_per_m3 * g)
    return np.minimum(limit, bubble.max_shear_m)


@dataclass(frozen=True)
class BubbleWrench:
    """One bubble's true contact wrench (on the membrane, from the object), tool frame.

    ``slipping_fraction`` is the share of the patch's area past its friction limit
    (0: all stuck, 1: the whole patch slips).
    """

    force_n: np.ndarray
    torque_nm: np.ndarray
    slipping_fraction: float
    area_m2: float

    @classmethod
    def none(cls) -> BubbleWrench:
        return cls(np.zeros(3), np.zeros(3), 0.0, 0.0)


def bubble_wrench(patch: PatchSamples, pressure_pa: float, bubble: BubbleSpec) -> BubbleWrench:
    """Sum of one bubble's sample tractions (see the module docstring)."""
    p = max(pressure_pa, 0.0)
    g = stiffening(patch.indentation_m, bubble.edge_stiffening)
    limit = slip_shift_m(p, g, bubble)
    shift = patch.shift_in_tool_m
    norm = np.linalg.norm(shift, axis=1)
    slipping = norm > limit * (1.0 - 1e-9)
    capped = shift * np.minimum(1.0, limit / np.maximum(norm, 1e-15))[:, None]
    tangential = (bubble.shear_stiffness_n_per_m3 * g * patch.area_m2)[:, None] * capped
    forces = np.zeros((len(norm), 3))
    forces[:, 1:] = tangential
    # The object pushes each sample towards the plate (against its inward normal).
    forces -= (p * patch.projected_m2)[:, None] * patch.normal_in_tool[None, :]
    torque = np.cross(patch.points_in_tool, forces).sum(axis=0)
    area = float(patch.area_m2.sum())
    fraction = float(patch.area_m2[slipping].sum() / area) if area > 0 else 0.0
    return BubbleWrench(forces.sum(axis=0), torque, fraction, float(patch.projected_m2.sum()))


@dataclass
class _Grip:
    """What one bubble's tangential force at a uniform shift needs (from the last frame)."""

    stiffness_n_per_m: np.ndarray  # k g a per sample
    limit_m: np.ndarray  # slip shift per sample

    def force(self, shift: np.ndarray) -> tuple[np.ndarray, float]:
        """Tangential force on the bubble at a uniform ``shift`` (2,), and the largest
        stuck shift (past it the whole patch slips)."""
        norm = float(np.hypot(shift[0], shift[1]))
        full = float(self.limit_m.max()) if self.limit_m.size else 0.0
        if norm <= 0.0:
            return np.zeros(2), full
        magnitude = float(np.sum(self.stiffness_n_per_m * np.minimum(norm, self.limit_m)))
        return shift * (magnitude / norm), full


@dataclass
class SlipDynamics:
    """The held object's slide in the hand (see the module docstring).

    ``offset_m`` is how far the object has moved from its scripted pose in the tool's
    (y, z) plane, ``velocity_m_per_s`` its rate. :meth:`step` integrates one frame with
    the grips of the last frame's contacts, dragging anchors that slip. Until the
    gripper holds the object with both bubbles (``held``, set by the world) the scene's
    trajectory holds it (a hand, a table); from then on the load is the gripper's to
    carry, and an object that loses both contacts falls.
    """

    load: LoadSpec
    bubble: BubbleSpec
    held: bool = False
    offset_m: np.ndarray = field(default_factory=lambda: np.zeros(2))
    velocity_m_per_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    grips: dict[str, _Grip] = field(default_factory=dict)

    def hold(self, side: str, patch: PatchSamples | None, pressure_pa: float) -> None:
        """Set a bubble's grip from its contact this frame (None: out of contact)."""
        if patch is None:
            self.grips.pop(side, None)
            return
        g = stiffening(patch.indentation_m, self.bubble.edge_stiffening)
        self.grips[side] = _Grip(
            self.bubble.shear_stiffness_n_per_m3 * g * patch.area_m2,
            slip_shift_m(pressure_pa, g, self.bubble),
        )

    def step(
        self, t_secs: float, dt_secs: float, stick_m: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """Advance from ``t_secs`` by ``dt_secs``.

        Args:
            stick_m: each anchored bubble's current stick shift (tool (y, z)), i.e. the
                object's offset from its anchor.

        Returns:
            How far each bubble's anchor was dragged (tool (y, z), metres).
        """
        drag = {s: np.zeros(2) for s in stick_m}
        if not self.held:
            return drag
        n = self.load.substeps
        h = dt_secs / n
        stick = {s: np.asarray(v, dtype=np.float64).copy() for s, v in stick_m.items()}
        for k in range(n):
            t = t_secs + (k + 1) * h
            load = self.load.force_at(t)[1:]
            total = load - self.load.damping_n_s_per_m * self.velocity_m_per_s
            for side, shift in stick.items():
                grip = self.grips.get(side)
                if grip is None:
                    continue
                force, full = grip.force(shift)
                norm = float(np.hypot(shift[0], shift[1]))
                if norm > full:
                    slid = shift * (1.0 - full / norm)
                    drag[side] += slid
                    shift -= slid
                total -= force
            accel = total / self.load.mass_at(t)
            self.velocity_m_per_s = self.velocity_m_per_s + accel * h
            step = self.velocity_m_per_s * h
            self.offset_m = self.offset_m + step
            for shift in stick.values():
                shift += step
        return drag
