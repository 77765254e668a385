"""Fields built from others: a rigid placement, a union."""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from geometry.fields.base import Field, as_points


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
        pts = as_points(points)
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
        pts = as_points(points)
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
