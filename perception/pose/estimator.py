"""The robust pose estimator: seeding, tracking, wrong-minimum detection and recovery.

Wraps any local solver (``LMSolver``, ``IpoptSolver``, ``IcpSolver``: each has
``solve(points_in_tool, object_from_tool_seed) -> FitResult``) with what the issue
asks for around it:

- Seeds: a given seed pose if any, else the last estimate (tracking warm start), else
  poses from the data and the cardinal poses (``common.seed_poses``).
- Wrong minima: a local solver can converge, and report success, with the axis about
  90 degrees off; such minima fit far worse than the depth noise. A result whose
  residual RMS exceeds ``accept_ratio * noise_m`` is rejected, and the solve is re-run
  from the estimate turned 90 degrees about each of its object axes, turned over, and
  from the data and cardinal seeds; the lowest cost wins. A cold start (no prior)
  always checks its first minimum against the turns. ``status`` says ``ok`` (the first
  solve fit within the threshold), ``recovered`` (it did not; a re-seed did) or
  ``suspect`` (nothing fits that well; the lowest cost is returned). Every
  result reports ``seeds_tried``.
- Degenerate input: fewer than ``min_points`` finite points gives ``no_patch`` with the
  prior pose (seed, last estimate, or identity), residual 0 and nothing observable;
  a solver error or a non-finite pose gives ``failed`` with the seed pose. Never an
  exception for bad data, never a NaN pose.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose.common import FitResult, clean_points, residuals, seed_poses


class LocalSolver(Protocol):
    name: str
    field: Field

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult: ...


@dataclass(frozen=True, kw_only=True)
class EstimatorParams:
    """Knobs of the robust wrapper.

    Attributes:
        noise_m: the depth noise sigma the patches carry (docs/facts.md: about 1.5 mm).
        accept_ratio: a minimum whose residual RMS exceeds ``accept_ratio * noise_m``
            is taken as wrong. Noise along the camera rays leaves an RMS of about 0.7
            sigma at the right pose; the 90-degree wrong minima leave about 2 sigma.
        min_points: below this many finite points there is no estimate.
        max_points: the cloud is subsampled (fixed seed) to at most this many points.
        max_seeds: at most this many solves per estimate (first one included).
        track: warm-start from the last estimate.
    """

    noise_m: float = 0.0015
    accept_ratio: float = 1.3
    min_points: int = 10
    max_points: int = 10000
    max_seeds: int = 14
    track: bool = True

    @property
    def accept_rms_m(self) -> float:
        """Residual RMS above which a minimum is taken as wrong."""
        return self.accept_ratio * self.noise_m

    def __post_init__(self) -> None:
        for name in ("noise_m", "accept_ratio"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if self.min_points < 6:
            raise ValueError(f"min_points must be >= 6 (six unknowns), got {self.min_points}")
        if self.max_points < self.min_points:
            raise ValueError(f"max_points must be >= min_points, got {self.max_points}")
        if self.max_seeds < 1:
            raise ValueError(f"max_seeds must be >= 1, got {self.max_seeds}")


def _turns(object_from_tool: np.ndarray, *, yaw: bool) -> list[np.ndarray]:
    """The estimate turned 90 degrees both ways about the object's x and y axes, and
    over; with ``yaw``, also about z (objects that are not bodies of revolution)."""
    out = []
    if yaw:
        for angle in (np.pi / 2, -np.pi / 2, np.pi):
            turn = se3.rotation_about(np.array([0.0, 0.0, 1.0]), angle)
            out.append(se3.make_pose(turn) @ object_from_tool)
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        for angle in (np.pi / 2, -np.pi / 2, np.pi):
            if angle == np.pi and axis[1] == 1.0:
                continue  # turning over about x or about y differ by a yaw only
            out.append(se3.make_pose(se3.rotation_about(axis, angle)) @ object_from_tool)
    return out


class PoseEstimator:
    """Estimates ``object_from_tool`` from grasp clouds, one call per patch."""

    def __init__(
        self,
        solver: LocalSolver,
        params: EstimatorParams | None = None,
        *,
        symmetric_about_z: bool = True,
    ) -> None:
        self.solver = solver
        self.params = params or EstimatorParams()
        # Yaw turns only help where yaw is observable at all.
        self.yaw_turns = not symmetric_about_z
        self.last_object_from_tool: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the last estimate (the next call starts cold)."""
        self.last_object_from_tool = None

    def estimate(
        self,
        points_in_tool: np.ndarray,
        bubble: np.ndarray | None = None,
        *,
        seed_tool_from_object: np.ndarray | None = None,
    ) -> FitResult:
        """One estimate from a grasp cloud (tool frame); NaN rows are dropped.

        Args:
            points_in_tool: (N, 3) points.
            bubble: (N,) which bubble saw each point (0 left, 1 right), for seeding.
            seed_tool_from_object: a prior pose (e.g. from vision); overrides tracking.
        """
        start = time.perf_counter()
        prm = self.params
        raw = np.asarray(points_in_tool, dtype=np.float64).reshape(-1, 3)
        finite = np.all(np.isfinite(raw), axis=1)
        sides = None
        if bubble is not None and len(bubble) == len(raw):
            sides = np.asarray(bubble)[finite]
        pts = raw[finite]
        if len(pts) > prm.max_points:
            idx = np.sort(np.random.default_rng(0).choice(len(pts), prm.max_points, replace=False))
            pts = pts[idx]
            sides = sides[idx] if sides is not None else None
        pts = clean_points(pts)

        prior: np.ndarray | None = None
        if seed_tool_from_object is not None and np.all(np.isfinite(seed_tool_from_object)):
            prior = se3.invert(np.asarray(seed_tool_from_object, dtype=np.float64))
        elif prm.track and self.last_object_from_tool is not None:
            prior = self.last_object_from_tool

        if len(pts) < prm.min_points:
            pose = prior if prior is not None else np.eye(4)
            return FitResult(
                object_from_tool=pose,
                residual_rms_m=0.0,
                cost=0.0,
                iterations=0,
                status="no_patch",
                solve_secs=time.perf_counter() - start,
                points_used=len(pts),
                solver=self.solver.name,
                seeds_tried=0,
            )

        data_seeds = [se3.invert(s) for s in seed_poses(pts, sides)]
        queue = [prior] if prior is not None else []
        queue += data_seeds
        best: FitResult | None = None
        tried = 0
        iterations = 0
        turned = False
        cold = prior is None
        checks = 0  # turns still to solve before a good minimum may end the search
        first_good: bool | None = None
        while queue and tried < prm.max_seeds:
            seed = queue.pop(0)
            tried += 1
            result = self._solve(pts, seed)
            iterations += result.iterations
            if best is None or result.cost < best.cost:
                best = result
            good = best.status == "ok" and best.residual_rms_m <= prm.accept_rms_m
            if first_good is None:
                first_good = good
            if not turned and best.status == "ok" and (cold or not good):
                # The usual wrong minimum is the axis about 90 degrees off: try turns
                # first. Without a prior every turn is solved (a wrong minimum can fit
                # within the threshold on a noisy patch); with one, only until one fits.
                turns = _turns(best.object_from_tool, yaw=self.yaw_turns)
                queue = turns + queue
                turned = True
                checks = len(turns) if cold else 0
                continue
            if checks > 0:
                checks -= 1
                if checks > 0:
                    continue
            if good:
                break
        assert best is not None
        if best.status != "ok":
            status = best.status  # every solve failed: the first seed, with its fit
        elif best.residual_rms_m > prm.accept_rms_m:
            status = "suspect"
        elif not first_good:
            status = "recovered"
        else:
            status = "ok"
        final = replace(
            best,
            status=status,
            iterations=iterations,
            seeds_tried=tried,
            solve_secs=time.perf_counter() - start,
        )
        if status in ("ok", "recovered"):
            self.last_object_from_tool = final.object_from_tool
        return final

    def _solve(self, pts: np.ndarray, seed: np.ndarray) -> FitResult:
        start = time.perf_counter()
        try:
            result = self.solver.solve(pts, seed)
            if np.all(np.isfinite(result.object_from_tool)) and np.isfinite(result.cost):
                return result
            message = "non-finite pose or cost"
        except (np.linalg.LinAlgError, ValueError, RuntimeError, FloatingPointError) as err:
            message = f"{type(err).__name__}: {err}"
        # The seed is returned with its own (finite) fit, so the caller still has a pose.
        r = residuals(self.solver.field, seed, pts)
        r = r[np.isfinite(r)]
        cost = float(r @ r) if len(r) else 0.0
        return FitResult(
            object_from_tool=seed,
            residual_rms_m=float(np.sqrt(cost / max(len(r), 1))),
            cost=cost,
            iterations=0,
            status="failed",
            solve_secs=time.perf_counter() - start,
            points_used=len(pts),
            solver=self.solver.name,
            message=message,
        )
