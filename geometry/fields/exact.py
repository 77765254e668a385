"""Fields that are exact signed distances: sphere and capsule."""

from __future__ import annotations

import casadi as ca
import numpy as np

from geometry.fields.base import Field, as_points, positive, safe_inv, safe_norm_ca, safe_norm_np


class Sphere(Field):
    """A sphere at the origin: the exact signed distance ``||p|| - r``."""

    @property
    def revolves_about_z(self) -> bool:
        return True

    def __init__(self, radius_m: float) -> None:
        self.radius_m = positive("radius_m", radius_m)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = as_points(points)
        norm = safe_norm_np(np.einsum("nj,nj->n", pts, pts))
        return norm - self.radius_m, pts * safe_inv(norm)[:, None]

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        return safe_norm_ca(ca.sumsqr(p)) - self.radius_m

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
        self.radius_m = positive("radius_m", radius_m)
        self.length_m = positive("length_m", length_m)

    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = as_points(points)
        v = pts.copy()
        v[:, 2] -= np.clip(pts[:, 2], -self.length_m / 2, self.length_m / 2)
        norm = safe_norm_np(np.einsum("nj,nj->n", v, v))
        return norm - self.radius_m, v * safe_inv(norm)[:, None]

    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        half = self.length_m / 2
        vz = p[2] - ca.fmin(ca.fmax(p[2], -half), half)
        return safe_norm_ca(p[0] ** 2 + p[1] ** 2 + vz**2) - self.radius_m

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
