"""Point-to-point ICP against a sampled model surface: the baseline soft-bubble code uses.

docs/facts.md: public pipelines run Open3D point-to-point ICP with a 5 mm correspondence
distance and up to 1000 iterations. Here the model surface is sampled once (uniform
by area, object frame) into a k-d tree; each iteration pairs every tool point, moved
by the current ``object_from_tool``, with its nearest model point within
``max_correspondence_m`` and solves the best rigid update in closed form (Kabsch).
Stops when the RMS of the pairs changes by less than ``rms_tol_m`` or after
``max_iterations``. The residual reported is the proximity field's, as for the other
solvers, so results compare.
"""

from __future__ import annotations

import functools
import time
from typing import TYPE_CHECKING, Annotated

import msgspec
import numpy as np
from msgspec import Meta

from geometry.fields import Field
from perception.pose.problem import (
    FitResult,
    characteristic_length,
    check_problem,
    observability,
    residuals_and_jacobian,
    scaled_information,
)

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


class IcpParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Knobs of the ICP baseline (defaults from docs/facts.md, iterations capped lower)."""

    max_correspondence_m: Annotated[float, Meta(gt=0.0)] = 0.005
    max_iterations: Annotated[int, Meta(ge=1)] = 100
    rms_tol_m: float = 1e-7
    model_points: Annotated[int, Meta(ge=100)] = 40000
    observability_floor: float = 1e-4


@functools.lru_cache(maxsize=8)
def _model_tree(fld: Field, n: int) -> tuple[np.ndarray, cKDTree]:
    from scipy.spatial import cKDTree  # only when ICP runs: 0.4 s a node need not pay

    pts = fld.sample_surface(n, np.random.default_rng(12345))
    return pts, cKDTree(pts)


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rigid 4x4 ``T`` minimizing ``sum ||T src_i - dst_i||^2`` (no reflection)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = cd - rot @ cs
    return out


class IcpSolver:
    """Local point-to-point ICP from one seed."""

    name = "icp"

    def __init__(self, fld: Field, params: IcpParams | None = None) -> None:
        self.field = fld
        self.params = params or IcpParams()
        self.length_m = characteristic_length(fld)
        self.model_points, self.tree = _model_tree(fld, self.params.model_points)

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult:
        """Refine ``object_from_tool`` on finite (N, 3) tool-frame points spread in 3-D.

        Raises:
            ValueError: bad points or a seed that is not rigid (``problem.check_problem``).
        """
        start = time.perf_counter()
        prm = self.params
        pts, pose = check_problem(points_in_tool, object_from_tool)
        pose = pose.copy()
        last_rms = np.inf
        iterations = 0
        converged = False
        for iterations in range(1, prm.max_iterations + 1):  # noqa: B007 - count survives
            moved = pts @ pose[:3, :3].T + pose[:3, 3]
            dist, idx = self.tree.query(moved, distance_upper_bound=prm.max_correspondence_m)
            pair = np.isfinite(dist)
            if int(pair.sum()) < 3:
                break  # nothing within reach: not converged
            update = kabsch(moved[pair], self.model_points[idx[pair]])
            pose = update @ pose
            rms = float(np.sqrt(np.mean(dist[pair] ** 2)))
            if abs(last_rms - rms) < prm.rms_tol_m:
                converged = True
                break
            last_rms = rms
        r, jac = residuals_and_jacobian(self.field, pose, pts)
        flags, _, _ = observability(scaled_information(jac, self.length_m), prm.observability_floor)
        cost = float(r @ r)
        return FitResult(
            object_from_tool=pose,
            residual_rms_m=float(np.sqrt(cost / max(len(pts), 1))),
            residual_mean_m=float(np.mean(r)),
            cost=cost,
            iterations=iterations,
            status="ok" if converged else "not_converged",
            solve_secs=time.perf_counter() - start,
            points_used=len(pts),
            observable=flags,
            solver=self.name,
            message="" if converged else "no convergence within max_iterations or reach",
        )
