"""Proximity fields: the paper's corner-corrected capped cylinder, its siblings, unions.

A proximity field ``phi`` maps a point in the field's frame to a scalar: ``phi >= 0``
outside, ``phi < 0`` inside, ``0`` on the surface (paper, "Proximity Pose
Estimation"). Every field here offers the same three views of one formula:

- ``value(points)``: (N, 3) float64 points to (N,) values, vectorized numpy;
- ``value_and_grad(points)``: values and (N, 3) gradients, analytic, vectorized numpy;
- ``casadi(p)``: the value as a CasADi expression of a 3x1 ``SX``/``MX`` symbol.

The "slab" primitives (cylinder, box, frustum) use the paper's combination of a slab
vector ``delta`` (one signed distance per pair of parallel faces, or per side)::

    phi = || max(delta, 0) ||_2 + vmax(min(delta, 0))

which is the Euclidean distance to the nearest edge or corner outside (the corner
correction) and the distance to the nearest face inside. Sphere and capsule are exact
signed distances.

Finite everywhere, by construction, for values and gradients. The outer norm
``||max(delta, 0)||`` is ``sqrt(0)`` for every point inside the surface (half of a
noisy patch) and its plain derivative there is NaN; an epsilon only inside the radial
norm ``||p_xy||`` does not cure it. So every gradient of a norm is written
``v / max(||v||, 1e-15)`` in numpy (exactly ``v / ||v||`` above 1e-15 m, zero at
``v = 0``), and every CasADi norm is ``if_else(s > EPS2, sqrt(max(s, EPS2)), 0)``, whose
branches are both finite with finite derivatives, so no NaN leaks into a Jacobian or a
Hessian. Values agree between the two to 1e-15 m. On the cylinder axis the radial
gradient is zero (the field is not differentiable there; zero is its minimum-norm
subgradient). Gradients have unit length outside right-angled slabs (Eikonal); at a
frustum's slanted rim they reach ``1/sin`` of the rim angle.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import casadi as ca
import numpy as np

# Floor under every squared norm: sqrt(1e-30) = 1e-15 m, far below any depth noise.
EPS2 = 1e-30


def _points(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 1:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    return pts


def _safe_norm_np(sq: np.ndarray) -> np.ndarray:
    """sqrt of a squared norm (a sum of squares, so >= 0: the value itself is safe)."""
    return np.sqrt(sq)


def _safe_inv(norm: np.ndarray) -> np.ndarray:
    """1 / max(norm, sqrt(EPS2)): finite, and a zero norm's numerator is zero too.

    A gradient ``v / ||v||`` becomes ``v * _safe_inv(||v||)``: exactly ``v / ||v||``
    above 1e-15 m, zero at ``v = 0``, and never longer than 1 in between.
    """
    return 1.0 / np.maximum(norm, np.sqrt(EPS2))


def _safe_norm_ca(sq: ca.SX | ca.MX) -> ca.SX | ca.MX:
    return ca.if_else(sq > EPS2, ca.sqrt(ca.fmax(sq, EPS2)), 0.0)


class Field(ABC):
    """A proximity field in its own frame. Subclasses implement the three views."""

    @abstractmethod
    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values (N,) and gradients (N, 3) at (N, 3) points of the field's frame."""

    def value(self, points: np.ndarray) -> np.ndarray:
        """Values (N,) at (N, 3) points of the field's frame."""
        return self.value_and_grad(points)[0]

    @abstractmethod
    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        """The value as a CasADi expression of a 3x1 symbol ``p``."""

    @abstractmethod
    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min_xyz, max_xyz)`` of the surface, metres."""

    @abstractmethod
    def area_m2(self) -> float:
        """Surface area (of the primitive; a union overcounts hidden parts)."""

    @abstractmethod
    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` points drawn uniformly by area on the surface, (n, 3)."""

    @property
    def revolves_about_z(self) -> bool:
        """True for a body of revolution about the frame's z axis (yaw is invisible)."""
        return False

    @property
    def dims_m(self) -> dict[str, float]:
        """The dimensions a fit may adjust (``casadi_sized``, ``resized``); none by default."""
        return {}

    def casadi_sized(self, p: ca.SX | ca.MX, dims: dict[str, ca.SX | ca.MX]) -> ca.SX | ca.MX:
        """The value with some of :attr:`dims_m` replaced by CasADi symbols."""
        if dims:
            raise ValueError(f"{type(self).__name__} has no adjustable dims, got {sorted(dims)}")
        return self.casadi(p)

    def resized(self, **dims: float) -> Field:
        """The same field with some of :attr:`dims_m` changed."""
        if dims:
            raise ValueError(f"{type(self).__name__} has no adjustable dims, got {sorted(dims)}")
        return self


class SlabField(Field):
    """A primitive whose field is the paper's slab combination of ``delta``."""

    @abstractmethod
    def slab(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``delta`` (N, k) and its Jacobian (N, k, 3)."""

    @abstractmethod
    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        """``delta`` as a list of k CasADi scalars."""

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = _points(points)
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
    return _safe_norm_ca(sq) + ca.fmin(dmax, 0.0)


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
    outer = _safe_norm_np(sq)
    inv = _safe_inv(outer)
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
    rho = _safe_norm_np(pts[:, 0] ** 2 + pts[:, 1] ** 2)
    inv = _safe_inv(rho)
    grad = np.zeros_like(pts)
    grad[:, 0] = pts[:, 0] * inv
    grad[:, 1] = pts[:, 1] * inv
    return rho, grad


def _sized(fld: Field, dims: dict) -> dict:
    """``fld.dims_m`` updated by ``dims``; unknown names are an error naming them."""
    unknown = sorted(set(dims) - set(fld.dims_m))
    if unknown:
        raise ValueError(
            f"{type(fld).__name__}: unknown dims {unknown}; valid: {sorted(fld.dims_m)}"
        )
    return {**fld.dims_m, **dims}


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


class CappedCylinder(SlabField):
    """The paper's capped cylinder: axis on z, origin at half height.

    ``delta = |[||p_xy||, z]| - [r, h/2]`` and the slab combination (paper, eq. of
    the cylinder proximity field).
    """

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_m: float, height_m: float) -> None:
        self.radius_m = _positive("radius_m", radius_m)
        self.height_m = _positive("height_m", height_m)

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
        pts = _points(points)
        rho = _safe_norm_np(pts[:, 0] ** 2 + pts[:, 1] ** 2)
        value, (w_rho, w_z) = _slab_combine(
            [rho - self.radius_m, np.abs(pts[:, 2]) - 0.5 * self.height_m]
        )
        radial = w_rho * _safe_inv(rho)
        grad = np.empty_like(pts)
        grad[:, 0] = radial * pts[:, 0]
        grad[:, 1] = radial * pts[:, 1]
        grad[:, 2] = w_z * np.sign(pts[:, 2])
        return value, grad

    def slab_casadi(self, p: ca.SX | ca.MX) -> list[ca.SX | ca.MX]:
        return self._slab_sized(p, self.radius_m, self.height_m)

    @staticmethod
    def _slab_sized(p: ca.SX | ca.MX, radius: object, height: object) -> list[ca.SX | ca.MX]:
        rho = _safe_norm_ca(p[0] ** 2 + p[1] ** 2)
        return [rho - radius, ca.fabs(p[2]) - 0.5 * height]

    @property
    def dims_m(self) -> dict[str, float]:
        return {"radius_m": self.radius_m, "height_m": self.height_m}

    def casadi_sized(self, p: ca.SX | ca.MX, dims: dict[str, ca.SX | ca.MX]) -> ca.SX | ca.MX:
        sized = _sized(self, dims)
        return _slab_casadi_combine(self._slab_sized(p, sized["radius_m"], sized["height_m"]))

    def resized(self, **dims: float) -> Field:
        sized = _sized(self, dims)
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
        size = [_positive(f"size_m[{i}]", s) for i, s in enumerate(size_m)]
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
        self.radius_bottom_m = _positive("radius_bottom_m", radius_bottom_m)
        self.radius_top_m = _positive("radius_top_m", radius_top_m)
        self.height_m = _positive("height_m", height_m)
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
        rho = _safe_norm_ca(p[0] ** 2 + p[1] ** 2)
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


class Sphere(Field):
    """A sphere at the origin: the exact signed distance ``||p|| - r``."""

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_m: float) -> None:
        self.radius_m = _positive("radius_m", radius_m)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = _points(points)
        norm = _safe_norm_np(np.einsum("nj,nj->n", pts, pts))
        return norm - self.radius_m, pts * _safe_inv(norm)[:, None]

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        return _safe_norm_ca(ca.sumsqr(p)) - self.radius_m

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        r = self.radius_m
        return np.full(3, -r), np.full(3, r)

    def area_m2(self) -> float:
        return 4.0 * np.pi * self.radius_m**2

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        v = rng.normal(size=(n, 3))
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
        return v * self.radius_m


class Capsule(Field):
    """A capsule on z: the segment ``z in [-L/2, L/2]`` swept by a ball of radius r."""

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_m: float, length_m: float) -> None:
        self.radius_m = _positive("radius_m", radius_m)
        self.length_m = _positive("length_m", length_m)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = _points(points)
        v = pts.copy()
        v[:, 2] -= np.clip(pts[:, 2], -self.length_m / 2, self.length_m / 2)
        norm = _safe_norm_np(np.einsum("nj,nj->n", v, v))
        return norm - self.radius_m, v * _safe_inv(norm)[:, None]

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        half = self.length_m / 2
        vz = p[2] - ca.fmin(ca.fmax(p[2], -half), half)
        return _safe_norm_ca(p[0] ** 2 + p[1] ** 2 + vz**2) - self.radius_m

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        r, hh = self.radius_m, self.length_m / 2 + self.radius_m
        return np.array([-r, -r, -hh]), np.array([r, r, hh])

    def area_m2(self) -> float:
        r = self.radius_m
        return 2.0 * np.pi * r * self.length_m + 4.0 * np.pi * r * r

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        r, half = self.radius_m, self.length_m / 2
        on_side = rng.random(n) < 2.0 * np.pi * r * self.length_m / self.area_m2()
        phi = rng.uniform(0, 2 * np.pi, n)
        side = np.stack([r * np.cos(phi), r * np.sin(phi), rng.uniform(-half, half, n)], axis=1)
        ball = Sphere(r).sample_surface(n, rng)
        ball[:, 2] += np.where(ball[:, 2] >= 0.0, half, -half)
        return np.where(on_side[:, None], side, ball)


class Transformed(Field):
    """A child field placed in a parent frame by ``parent_from_child`` (rigid 4x4)."""

    def __init__(self, child: Field, parent_from_child: np.ndarray) -> None:
        pose = np.asarray(parent_from_child, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"parent_from_child must be a finite 4x4, got shape {pose.shape}")
        rot = pose[:3, :3]
        if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-9):
            raise ValueError("parent_from_child must be a rigid transform (orthonormal rotation)")
        self.child = child
        self.parent_from_child = pose
        self._rot_cp = rot.T  # child_from_parent rotation
        self._trans_cp = -rot.T @ pose[:3, 3]

    @property
    def revolves_about_z(self) -> bool:
        pose = self.parent_from_child
        on_axis = np.allclose(pose[:2, 3], 0.0) and np.allclose(pose[:3, 2], [0.0, 0.0, 1.0])
        return bool(on_axis and self.child.revolves_about_z)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = _points(points)
        value, grad_child = self.child.value_and_grad(pts @ self._rot_cp.T + self._trans_cp)
        return value, grad_child @ self._rot_cp

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        return self.child.casadi(ca.mtimes(ca.DM(self._rot_cp), p) + ca.DM(self._trans_cp))

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.child.bounds_m()
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        moved = corners @ self.parent_from_child[:3, :3].T + self.parent_from_child[:3, 3]
        return moved.min(axis=0), moved.max(axis=0)

    def area_m2(self) -> float:
        return self.child.area_m2()

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        pts = self.child.sample_surface(n, rng)
        return pts @ self.parent_from_child[:3, :3].T + self.parent_from_child[:3, 3]


class Union(Field):
    """The union of fields: the minimum value, the gradient of the minimizing child."""

    def __init__(self, children: Sequence[Field]) -> None:
        if len(children) == 0:
            raise ValueError("children must hold at least one field, got 0")
        self.children = list(children)

    @property
    def revolves_about_z(self) -> bool:
        return all(c.revolves_about_z for c in self.children)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = _points(points)
        results = [c.value_and_grad(pts) for c in self.children]
        values = np.stack([r[0] for r in results], axis=1)
        best = np.argmin(values, axis=1)
        rows = np.arange(len(pts))
        grads = np.stack([r[1] for r in results], axis=1)
        return values[rows, best], grads[rows, best]

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        out = self.children[0].casadi(p)
        for child in self.children[1:]:
            out = ca.fmin(out, child.casadi(p))
        return out

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        boxes = [c.bounds_m() for c in self.children]
        return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)

    def area_m2(self) -> float:
        return float(sum(c.area_m2() for c in self.children))

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Samples of the union's outer surface: children's samples not inside another."""
        areas = np.array([c.area_m2() for c in self.children])
        chunks: list[np.ndarray] = []
        got = 0
        for _ in range(50):
            if got >= n:
                break
            want = 2 * (n - got) + 16
            counts = rng.multinomial(want, areas / areas.sum())
            pts = np.concatenate(
                [c.sample_surface(int(k), rng) for c, k in zip(self.children, counts, strict=True)]
            )
            keep = pts[self.value(pts) > -1e-9]
            chunks.append(keep)
            got += len(keep)
        pts = np.concatenate(chunks) if chunks else np.zeros((0, 3))
        return pts[rng.permutation(len(pts))[:n]]


def casadi_function(field: Field, name: str = "phi", *, symbolic: str = "SX") -> ca.Function:
    """A CasADi function ``p (3x1) -> phi`` of a field (SX by default, MX on request)."""
    sym = ca.SX if symbolic == "SX" else ca.MX
    p = sym.sym("p", 3)
    return ca.Function(name, [p], [field.casadi(p)])
