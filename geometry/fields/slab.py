"""The paper's slab combination and its primitives: capped cylinder, box, frustum."""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence

import casadi as ca
import numpy as np

from geometry.fields.base import (
    Field,
    as_points,
    merged_dims,
    positive,
    safe_inv,
    safe_norm_ca,
    safe_norm_np,
)


class SlabField(Field):
    """A primitive whose field is the paper's slab combination of ``delta``."""

    @abstractmethod
    def slab(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``delta`` (N, k) and its Jacobian (N, k, 3)."""

    @abstractmethod
    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        """``delta`` as a list of k CasADi scalars."""

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = as_points(points)
        delta, jac = self.slab(pts)
        value, weights = _slab_combine([delta[:, k] for k in range(delta.shape[1])])
        grad = np.zeros_like(pts)
        for k, w in enumerate(weights):
            grad += w[:, None] * jac[:, k]
        return value, grad

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        return _slab_casadi_combine(self.slab_casadi(p))


def _slab_casadi_combine(delta: Sequence[ca.SX | ca.MX]) -> ca.SX | ca.MX:
    """The slab combination of ``delta`` as a CasADi expression."""
    sq = 0.0
    for d in delta:
        sq = sq + ca.fmax(d, 0.0) ** 2
    dmax = delta[0]
    for d in delta[1:]:
        dmax = ca.fmax(dmax, d)
    return safe_norm_ca(sq) + ca.fmin(dmax, 0.0)


def _slab_combine(cols: Sequence[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The slab combination of the components of ``delta`` (k arrays of (N,)).

    Returns the values (N,) and d(value)/d(delta_k) for each k. The outer norm
    contributes ``max(delta, 0) / ||max(delta, 0)||`` (zero inside), the inner term a one
    on the first largest component when it is negative. Works column by column: numpy
    reductions over a short last axis are several times slower.
    """
    pos = [np.maximum(c, 0.0) for c in cols]
    sq = pos[0] * pos[0]
    for p in pos[1:]:
        sq = sq + p * p
    outer = safe_norm_np(sq)
    inv = safe_inv(outer)
    dmax = cols[0]
    for c in cols[1:]:
        dmax = np.maximum(dmax, c)
    # The inside term's one goes to the first largest component only (ties on the
    # medial surface would otherwise double the gradient).
    free = dmax <= 0.0  # on the surface too: a face normal, not a zero gradient
    weights = []
    for c, p in zip(cols, pos, strict=True):
        first = free & (c == dmax)
        free = free & ~first
        weights.append(p * inv + first)
    return outer + np.minimum(dmax, 0.0), weights


def _radial(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rho = ||p_xy|| (floored) and its gradient (zero on the axis)."""
    rho = safe_norm_np(pts[:, 0] ** 2 + pts[:, 1] ** 2)
    inv = safe_inv(rho)
    grad = np.zeros_like(pts)
    grad[:, 0] = pts[:, 0] * inv
    grad[:, 1] = pts[:, 1] * inv
    return rho, grad


class CappedCylinder(SlabField):
    """The paper's capped cylinder: axis on z, origin at half height.

    ``delta = |[||p_xy||, z]| - [r, h/2]`` and the slab combination (paper, eq. of
    the cylinder proximity field).
    """

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_m: float, height_m: float) -> None:
        self.radius_m = positive("radius_m", radius_m)
        self.height_m = positive("height_m", height_m)

    def slab(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rho, grho = _radial(pts)
        delta = np.stack([rho - self.radius_m, np.abs(pts[:, 2]) - 0.5 * self.height_m], axis=1)
        jac = np.zeros((len(pts), 2, 3))
        jac[:, 0] = grho
        jac[:, 1, 2] = np.sign(pts[:, 2])
        return delta, jac

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # The pose fit's hot path: the same formula as the generic slab path with the
        # Jacobian's structure (radial, axial) written out, about 3x faster.
        pts = as_points(points)
        rho = safe_norm_np(pts[:, 0] ** 2 + pts[:, 1] ** 2)
        value, (w_rho, w_z) = _slab_combine(
            [rho - self.radius_m, np.abs(pts[:, 2]) - 0.5 * self.height_m]
        )
        radial = w_rho * safe_inv(rho)
        grad = np.empty_like(pts)
        grad[:, 0] = radial * pts[:, 0]
        grad[:, 1] = radial * pts[:, 1]
        grad[:, 2] = w_z * np.sign(pts[:, 2])
        return value, grad

    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        return self._slab_sized(p, self.radius_m, self.height_m)

    @staticmethod
    def _slab_sized(p: ca.SX | ca.MX, radius: object, height: object) -> list[ca.SX | ca.MX]:
        rho = safe_norm_ca(p[0] ** 2 + p[1] ** 2)
        return [rho - radius, ca.fabs(p[2]) - 0.5 * height]

    @property
    def dims_m(self) -> dict[str, float]:
        return {"radius_m": self.radius_m, "height_m": self.height_m}

    def casadi_sized(self, p: ca.SX | ca.MX, dims: dict[str, ca.SX | ca.MX]) -> ca.SX | ca.MX:
        sized = merged_dims(self, dims)
        return _slab_casadi_combine(self._slab_sized(p, sized["radius_m"], sized["height_m"]))

    def resized(self, **dims: float) -> Field:
        sized = merged_dims(self, dims)
        return CappedCylinder(sized["radius_m"], sized["height_m"])

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        r, hh = self.radius_m, 0.5 * self.height_m
        return np.array([-r, -r, -hh]), np.array([r, r, hh])

    def area_m2(self) -> float:
        r = self.radius_m
        return 2.0 * np.pi * r * self.height_m + 2.0 * np.pi * r * r

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        r, h = self.radius_m, self.height_m
        side = 2.0 * np.pi * r * h
        on_side = rng.random(n) < side / self.area_m2()
        phi = rng.uniform(0.0, 2.0 * np.pi, n)
        rad = np.where(on_side, r, r * np.sqrt(rng.random(n)))
        z = np.where(on_side, rng.uniform(-h / 2, h / 2, n), np.sign(rng.random(n) - 0.5) * h / 2)
        return np.stack([rad * np.cos(phi), rad * np.sin(phi), z], axis=1)


class Box(SlabField):
    """An axis-aligned box centred at the origin; ``delta = |p| - half_extents``."""

    def __init__(self, size_m: Sequence[float]) -> None:
        size = [positive(f"size_m[{i}]", s) for i, s in enumerate(size_m)]
        if len(size) != 3:
            raise ValueError(f"size_m must have 3 entries, got {len(size)}")
        self.half_m = 0.5 * np.asarray(size)

    def slab(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        delta = np.abs(pts) - self.half_m
        jac = np.zeros((len(pts), 3, 3))
        idx = np.arange(3)
        jac[:, idx, idx] = np.sign(pts)
        return delta, jac

    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        return [ca.fabs(p[i]) - float(self.half_m[i]) for i in range(3)]

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        return -self.half_m.copy(), self.half_m.copy()

    def area_m2(self) -> float:
        a, b, c = 2.0 * self.half_m
        return 2.0 * (a * b + b * c + a * c)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        h = self.half_m
        face_areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]])  # faces normal to x, y, z
        axis = rng.choice(3, size=n, p=face_areas / face_areas.sum())
        pts = rng.uniform(-h, h, size=(n, 3))
        sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        pts[np.arange(n), axis] = sign * h[axis]
        return pts


class Frustum(SlabField):
    """A truncated cone on z, origin at half height: radius ``radius_bottom_m`` at
    ``z = -h/2`` and ``radius_top_m`` at ``z = +h/2`` (the paper's future work).

    ``delta = [(rho - r(z)) / sqrt(1 + k^2), |z| - h/2]`` with ``r(z)`` linear of slope
    ``k``: the first entry is the signed distance to the slanted side line in the
    ``(rho, z)`` half plane. The slab combination then gives zero on the surface,
    negative inside and a C1 positive field outside; near the rims it is the corner
    corrected ``sqrt(d_side^2 + d_cap^2)``, exact for a cylinder (k = 0) and a close
    proximity for modest slopes.
    """

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_bottom_m: float, radius_top_m: float, height_m: float) -> None:
        self.radius_bottom_m = positive("radius_bottom_m", radius_bottom_m)
        self.radius_top_m = positive("radius_top_m", radius_top_m)
        self.height_m = positive("height_m", height_m)
        self._slope = (self.radius_top_m - self.radius_bottom_m) / self.height_m
        self._mid = 0.5 * (self.radius_top_m + self.radius_bottom_m)
        self._norm = float(np.sqrt(1.0 + self._slope**2))

    def slab(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rho, grho = _radial(pts)
        side = (rho - self._mid - self._slope * pts[:, 2]) / self._norm
        delta = np.stack([side, np.abs(pts[:, 2]) - 0.5 * self.height_m], axis=1)
        jac = np.zeros((len(pts), 2, 3))
        jac[:, 0] = grho / self._norm
        jac[:, 0, 2] = -self._slope / self._norm
        jac[:, 1, 2] = np.sign(pts[:, 2])
        return delta, jac

    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        rho = safe_norm_ca(p[0] ** 2 + p[1] ** 2)
        side = (rho - self._mid - self._slope * p[2]) / self._norm
        return [side, ca.fabs(p[2]) - 0.5 * self.height_m]

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        r, hh = max(self.radius_bottom_m, self.radius_top_m), 0.5 * self.height_m
        return np.array([-r, -r, -hh]), np.array([r, r, hh])

    def _side_area(self) -> float:
        rb, rt = self.radius_bottom_m, self.radius_top_m
        return float(np.pi * (rb + rt) * np.hypot(rt - rb, self.height_m))

    def area_m2(self) -> float:
        return self._side_area() + np.pi * (self.radius_bottom_m**2 + self.radius_top_m**2)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        rb, rt, h = self.radius_bottom_m, self.radius_top_m, self.height_m
        areas = np.array([self._side_area(), np.pi * rb * rb, np.pi * rt * rt])
        part = rng.choice(3, size=n, p=areas / areas.sum())
        out = np.empty((n, 3))
        # Side: z with density proportional to r(z), by rejection (r is linear, ratio >= rmin/rmax).
        m = int(np.sum(part == 0))
        zs: list[np.ndarray] = []
        got = 0
        while got < m:
            z = rng.uniform(-h / 2, h / 2, 2 * (m - got) + 8)
            keep = rng.random(len(z)) * max(rb, rt) < self._mid + self._slope * z
            zs.append(z[keep])
            got += int(keep.sum())
        z = np.concatenate(zs)[:m] if m else np.zeros(0)
        phi = rng.uniform(0, 2 * np.pi, n)
        rad = np.empty(n)
        zz = np.empty(n)
        rad[part == 0] = self._mid + self._slope * z
        zz[part == 0] = z
        for k, (r, zc) in enumerate([(rb, -h / 2), (rt, h / 2)], start=1):
            sel = part == k
            rad[sel] = r * np.sqrt(rng.random(int(sel.sum())))
            zz[sel] = zc
        out[:, 0] = rad * np.cos(phi)
        out[:, 1] = rad * np.sin(phi)
        out[:, 2] = zz
        return out
