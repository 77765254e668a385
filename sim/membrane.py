"""The membrane model: where the bubble surface lies when an object presses into it.

Geometric, quasi-static model (documented in docs/sim.md):

* The rest membrane is the ellipsoid cap of ``geometry.gripper``.
* Where the object's proximity field is negative at a rest membrane point, the membrane
  conforms to the object: seen from the internal camera, the surface along a pixel's
  ray is the object's surface point nearest the camera on that ray (found by Newton
  steps on the field from the rest point back towards the camera). It never goes behind the acrylic plate: a bubble squeezed flat
  bottoms out there.
* Elsewhere the membrane keeps its rest shape: the volume the object displaces raises
  the pressure (``sim.pressure``) instead of bulging the free membrane out.

Contact mechanics on a grid of membrane samples (used for pressure, grip force, contact
and ground-truth shear without rendering an image) take the penetration depth along the
field as the local indentation: displaced volume = sum(indentation * area), contact
area = the projected area of the indented samples, normal force = gauge pressure times
that area (a thin membrane under pressure transmits p * A).

A tensioned membrane (``BubbleSpec.tension_n_per_m`` > 0, :class:`Tension`) adds a tent
around the contact and the pull along it; without tension (the default) nothing changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from geometry.se3 import invert


@dataclass(frozen=True)
class PatchSamples:
    """The membrane samples of one bubble in contact (what ``sim.friction`` integrates).

    ``points_in_tool`` are the pressed-in samples (tool frame), ``indentation_m`` how far
    each is pressed in, ``area_m2`` its membrane area and ``projected_m2`` that area
    projected on the plate, ``shift_in_tool_m`` the material's stick shift since the
    anchor (tool (y, z), capped at the stick limit; zero without an anchor) and
    ``normal_in_tool`` the plate's inward normal (the finger's x axis) in the tool frame.
    """

    points_in_tool: np.ndarray
    indentation_m: np.ndarray
    area_m2: np.ndarray
    projected_m2: np.ndarray
    shift_in_tool_m: np.ndarray
    normal_in_tool: np.ndarray


@dataclass(frozen=True)
class ContactState:
    """One bubble's contact with the object at one instant (sample-grid model)."""

    displaced_volume_m3: float
    contact_area_m2: float
    in_contact: bool
    shear_in_tool_m: np.ndarray  # (2,) mean tangential membrane shift, tool (y, z)
    samples: PatchSamples | None = None  # with ``keep_samples``, while in contact


NO_SHEAR = np.zeros(2)


@dataclass(frozen=True)
class Tension:
    """A tensioned membrane around a contact (``sim.rig.BubbleSpec.tension_n_per_m``).

    The geometric model keeps the free membrane at its rest shape, a slack membrane
    pressed by its gauge pressure alone. A taut one (an elastic shell, as MuJoCo's) is
    pulled in around the object: here the free membrane leaves the patch's edge as a
    straight tent falling towards the rest shape at the slope ``slope = p0 a / T`` (the
    rest gauge pressure ``p0`` over the cap's in-plane semi-axis ``a`` against the
    tension ``T``: steep when slack, shallow when taut), and the tension pulls the object
    along it with ``T sin(atan(slope))`` per metre of the patch's edge, whose length is
    taken as a circle's of the same area (``2 sqrt(pi A)``). The tent's own volume does
    not raise the pressure, and the ``wrench`` effect leaves the pull out. A model of the
    effect, not of a measured membrane: its purpose is training data that does not
    teach one membrane's look (docs/classifier.md).
    """

    tension_n_per_m: float
    slope: float

    @classmethod
    def of(cls, bubble: Any) -> Tension | None:
        """The tension of a ``BubbleSpec``; None for a slack membrane (0)."""
        t = float(bubble.tension_n_per_m)
        if t <= 0.0:
            return None
        return cls(t, bubble.inflation_pa * bubble.semi_axis_lateral_m / t)

    def force_n(self, contact_area_m2: float) -> float:
        """The tension's pull on the object across a patch of this (projected) area."""
        edge_m = 2.0 * math.sqrt(math.pi * max(contact_area_m2, 0.0))
        return self.tension_n_per_m * edge_m * self.slope / math.hypot(1.0, self.slope)

    def spread(self, indent_m: np.ndarray, pitch_m: np.ndarray) -> np.ndarray:
        """The indentation with the tent around the contact, on an image grid.

        ``pitch_m`` is each pixel's size on the membrane (``inf`` off it): the tent
        falls ``slope * pitch`` per pixel away from the patch (a dilation by a cone,
        in steps to the 8 neighbours), and nowhere goes below the indentation given.
        """
        out = np.asarray(indent_m, np.float32)
        fall = (self.slope * pitch_m).astype(np.float32)
        top = float(out.max()) if out.size else 0.0
        finite = fall[np.isfinite(fall)]
        if top <= 0.0 or finite.size == 0:
            return out
        kernel = np.ones((3, 3), np.uint8)
        for _ in range(min(int(math.ceil(top / max(float(finite.min()), 1e-6))), 200)):
            grown = np.maximum(out, cv2.dilate(out, kernel) - fall)
            if np.array_equal(grown, out):
                break
            out = grown
        return out


class CulledField:
    """An object's field evaluated only where it matters to the membrane, for speed.

    A union (``geometry.fields.Union``) evaluates every child at every point; here
    each child is evaluated only at points inside its bounding box grown by
    ``margin_m``, and points outside every grown box get the value ``margin_m`` (they
    are at least that far outside the object) with a zero gradient. Values within
    ``margin_m`` of the surface, and all values inside the object, are the shared
    field's own. The membrane needs nothing else: it asks whether rest points are
    inside and walks along rays that stay within a step of the surface.
    """

    def __init__(self, field: Any, margin_m: float = 0.005) -> None:
        from geometry.fields import Union

        children = list(field.children) if isinstance(field, Union) else [field]
        self.margin_m = margin_m
        self.parts = [(c, *c.bounds_m()) for c in children]
        lo = np.min([p[1] for p in self.parts], axis=0)
        hi = np.max([p[2] for p in self.parts], axis=0)
        self.bounds = (lo, hi)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(points)
        value = np.full(n, self.margin_m)
        grad = np.zeros((n, 3))
        for child, lo, hi in self.parts:
            idx = np.flatnonzero(cull_to_bounds(points, lo, hi, self.margin_m))
            if idx.size == 0:
                continue
            v, g = child.value_and_grad(points[idx])
            better = v < value[idx]
            value[idx[better]] = v[better]
            grad[idx[better]] = g[better]
        return value, grad

    def value(self, points: np.ndarray) -> np.ndarray:
        return self.value_and_grad(points)[0]


def cull_to_bounds(
    points: np.ndarray, lo: np.ndarray, hi: np.ndarray, margin_m: float
) -> np.ndarray:
    """Boolean mask of points inside the box ``[lo - margin, hi + margin]``."""
    return np.all((points >= lo - margin_m) & (points <= hi + margin_m), axis=1)


def contact_mechanics(
    *,
    field: object,
    bounds: tuple[np.ndarray, np.ndarray],
    samples: object,
    tool_from_finger: np.ndarray,
    tool_from_object: np.ndarray,
    anchor_tool_from_object: np.ndarray | None = None,
    max_shear_m: float = 0.006,
    keep_samples: bool = False,
) -> ContactState:
    """Indentation, contact area and shear of one bubble on its sample grid.

    Args:
        field: the object's proximity field (``value(points)``), object frame.
        bounds: the object's bounding box in its frame.
        samples: ``geometry.gripper.SurfaceSamples`` of the rest membrane (frame F).
        tool_from_finger: the bubble's plate frame in the tool frame.
        tool_from_object: the object's pose now.
        anchor_tool_from_object: the object's pose when this contact began (stick); None
            for no shear.
        max_shear_m: the stick limit: larger shifts slip and stay at this length.
        keep_samples: also return the pressed samples (:class:`PatchSamples`).
    """
    object_from_finger = invert(tool_from_object) @ tool_from_finger
    pts = samples.points_f @ object_from_finger[:3, :3].T + object_from_finger[:3, 3]
    near = cull_to_bounds(pts, bounds[0], bounds[1], 1e-4)
    if not near.any():
        return ContactState(0.0, 0.0, False, NO_SHEAR)
    idx = np.nonzero(near)[0]
    phi = field.value(pts[idx])
    inside = phi < 0
    if not inside.any():
        return ContactState(0.0, 0.0, False, NO_SHEAR)
    idx = idx[inside]
    # The membrane cannot be pushed behind the plate: indentation <= height above it.
    pen = np.minimum(-phi[inside], samples.points_f[idx, 0])
    area = samples.area_m2[idx]
    volume = float(np.sum(pen * area))
    projected = float(np.sum(area * samples.normals_f[idx, 0]))
    shear = NO_SHEAR
    shift = None
    p_tool = None
    if anchor_tool_from_object is not None or keep_samples:
        pts_f = samples.points_f[idx] - pen[:, None] * samples.normals_f[idx]
        p_tool = pts_f @ tool_from_finger[:3, :3].T + tool_from_finger[:3, 3]
    if anchor_tool_from_object is not None:
        assert p_tool is not None
        shift = material_shift(p_tool, tool_from_object, anchor_tool_from_object, max_shear_m)
        weights = pen * area
        shear = (weights @ shift[:, 1:]) / weights.sum()
    patch = None
    if keep_samples:
        assert p_tool is not None
        patch = PatchSamples(
            points_in_tool=p_tool,
            indentation_m=pen,
            area_m2=area,
            projected_m2=area * samples.normals_f[idx, 0],
            shift_in_tool_m=np.zeros((len(idx), 2)) if shift is None else shift[:, 1:],
            normal_in_tool=tool_from_finger[:3, 0].copy(),
        )
    return ContactState(volume, projected, True, shear, patch)


def material_shift(
    points_in_tool: np.ndarray,
    tool_from_object: np.ndarray,
    anchor_tool_from_object: np.ndarray,
    max_shear_m: float,
) -> np.ndarray:
    """How far the membrane material at each point was carried by the object (stick).

    Material touching the object at ``points_in_tool`` was, when the contact began, at
    ``anchor * inv(now) * p``; the shift is the difference, with the component along
    the plate normal (tool x) removed, and capped at ``max_shear_m`` (slip).

    Returns:
        ``(N, 3)`` shifts in the tool frame (x component zero).
    """
    back = anchor_tool_from_object @ invert(tool_from_object)
    origin = points_in_tool @ back[:3, :3].T + back[:3, 3]
    shift = points_in_tool - origin
    shift[:, 0] = 0.0
    norm = np.linalg.norm(shift, axis=1)
    scale = np.minimum(1.0, max_shear_m / np.maximum(norm, 1e-12))
    return shift * scale[:, None]


def march_to_surface(
    field: object,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    t_rest: np.ndarray,
    phi_rest: np.ndarray,
    grad_rest: np.ndarray,
    t_min: np.ndarray,
    steps: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Move from rest points inside the object back along their rays to its surface.

    Points start at ``origins + t_rest * directions`` (object frame, unit directions
    pointing away from the camera), where the field is ``phi_rest < 0`` with gradient
    ``grad_rest``. Each step is a Newton step on the field along the ray,
    ``t -= phi / (grad . d)``, limited to four times ``|phi|``; where the ray runs
    nearly parallel to the surface (``grad . d > -0.05``) it is a sphere-tracing step
    ``t += phi`` instead (towards the camera from inside, away from it from outside).
    For a convex object the first Newton step lands on or just outside the surface and
    later ones converge from outside. ``t`` is clamped to ``[t_min, t_rest]`` (the
    plate and the rest membrane).

    Returns:
        ``(t, grad)``: the ray parameter of the surface, and the field gradient at the
        last point evaluated (object frame, ``(N, 3)``), used for shading.
    """
    t, phi, grad = t_rest, phi_rest, grad_rest
    for i in range(steps):
        slope = np.einsum("ij,ij->i", grad, directions)
        steep = slope < -0.05
        # Newton, but never more than a few times the field's value: on rays that
        # graze the surface the tangent overshoots far past it.
        step = np.where(steep, -phi / np.where(steep, slope, -1.0), phi)
        step = np.clip(step, -4.0 * np.abs(phi), 4.0 * np.abs(phi))
        t = np.clip(t + step, t_min, t_rest)
        if i < steps - 1:
            phi, grad = field.value_and_grad(origins + t[:, None] * directions)
    return t, grad
