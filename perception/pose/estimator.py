"""The robust pose estimator: seeding, tracking, wrong-minimum detection and recovery.

Wraps any local solver (``LMSolver``, ``IpoptSolver``, ``IcpSolver``: each has
``solve(points_in_tool, object_from_tool_seed) -> FitResult``) with what a user needs
around it:

- A prior, solved once: the last accepted estimate (tracking) or a given seed (vision,
  the node's parameter) is solved from alone, and that one solve stands when it is
  judged ``ok`` (below), its residual RMS is within ``warm_accept_ratio`` times the
  noise (and, tracking, within ``track_rise_ratio`` times the last one), and the answer
  lies within ``warm_deg`` of the prior. Otherwise (the residual says the track is
  lost, or the seed was far or wrong), and on a cold start, the search below runs
  (with ``search`` off, a prior's one solve is judged and returned whatever the verdict).
- Search: the prior (if any), the data seeds (``seeds.seed_poses``: the axis along
  each patch's principal directions and the cardinal axes) and then the best
  minimum's turns (``seeds.turns``: 90 degrees about its x and y axes, over, and about
  z for objects that are not bodies of revolution; turns that are symmetries of the
  object are skipped) are solved on a subsample (``screen_points``); the best distinct
  minimum (up to the object's symmetry) and up to three close ones are polished on the
  full cloud.
- Judgement (``judge``), the same whatever solver found the answer, with the noise
  measured from the cloud itself (``cloud.estimate_noise_m``) unless ``noise_m`` is
  configured. An answer short of the minimum of the fit (ICP, a loose tolerance: a
  Gauss-Newton step beyond ``step_limit`` of the 95% region remains) is first taken
  up to ``GAUSS_NEWTON_STEPS`` (2) Gauss-Newton steps further, each kept if the cost
  does not rise. The uncertainty of
  the answer (``judge.uncertainty``: a covariance from the fit's curvature and
  residuals at the answer and the bias that noise along the camera rays leaves,
  calibrated so its 95% region holds the truth 95% of the time) decides, and the
  answer is moved by the bias it predicts (``judge.Uncertainty.correction``):
  ``suspect``, with the reasons in ``message``, when the answer is not within
  ``tolerance_deg`` and ``tolerance_m`` along the observable directions with 99.5%
  probability under that uncertainty (``judge.within_tolerance``), when the
  answer is still not at the minimum of the fit after that step, when the fit is
  worse than ``accept_ratio`` times the noise or biased, when another minimum that
  fits about as well (``ambiguity_ratio``) differs from it along an observable
  direction by more than the tolerance, or when fewer than ``min_observable``
  directions are observable; else ``ok`` when the first seed's minimum won and
  ``recovered`` when another seed's did. Directions the patch does not observe
  (``observable``) and other minima that agree on every observable direction
  (``alternatives``: a box face's slide or turn within the face, a bottle end over end)
  are reported, not held against the answer.
- Unobservable directions: the local solvers keep them at their seed. When the winner
  did not come from the prior, its unobservable translations are moved so the patch's
  centroid sits at the object's origin along them (a turned seed otherwise leaves a
  cylinder's patch at a cap).
- Degenerate input: fewer than ``min_points`` finite points, or points at one point, on
  a line or on a plane, give ``no_patch`` with the reason and the prior pose (seed,
  last estimate, or identity), residual 0 and nothing observable; a solver error or a
  non-finite pose gives ``failed`` with the seed pose. Bad points never raise and never
  give a NaN pose; a seed that is not rigid is a ``ValueError``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose import judge
from perception.pose.cloud import camera_rays, clean_cloud, clean_points, estimate_noise_m
from perception.pose.params import EstimatorParams
from perception.pose.problem import (
    FitResult,
    check_rigid,
    flatness_m,
    residuals,
    spread_problem,
)
from perception.pose.seeds import seed_poses, turns
from perception.pose.symmetry import pose_difference, symmetry_rotations

#: The most Gauss-Newton steps the judgement takes toward the minimum of the fit (one
#: left a solver stopped 3 degrees off a cylinder's minimum 0.53 of the 95% region short).
GAUSS_NEWTON_STEPS = 2


class LocalSolver(Protocol):
    name: str
    field: Field

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult: ...


@dataclass
class _Minimum:
    result: FitResult
    rank: int  # order of its seed (0: the prior, or the first data seed)


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
        fld = solver.field
        self._turn_is_symmetry = [
            any(np.allclose(t[:3, :3] @ r, np.eye(3)) for r in symmetry_rotations(fld))
            for t in turns(np.eye(4), yaw=self.yaw_turns)
        ]
        self._flip_is_symmetry = any(r[2, 2] < 0 for r in symmetry_rotations(fld))
        # Alternatives are compared up to the object's symmetry turns and, for a body of
        # revolution, end over end (a bottle's patch may see only its body; its ends
        # then trade places along the axis).
        flip = se3.rotation_about(np.array([1.0, 0.0, 0.0]), np.pi)
        self._turn_labels = [(r, "") for r in symmetry_rotations(fld)]
        if fld.revolves_about_z and not self._flip_is_symmetry:
            self._turn_labels.append((flip, "end over end"))
        self.last_object_from_tool: np.ndarray | None = None
        self.last_rms_m = 0.0
        self.last_noise_m = 0.0

    def reset(self) -> None:
        """Forget the last estimate (the next call starts cold)."""
        self.last_object_from_tool = None
        self.last_rms_m = 0.0
        self.last_noise_m = 0.0

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

        Raises:
            ValueError: a seed that is not a finite rigid 4x4 (bad points never raise).
        """
        start = time.perf_counter()
        prm = self.params
        pts, sides = clean_cloud(points_in_tool, bubble, prm.max_points)
        tracking = False
        prior: np.ndarray | None = None
        if seed_tool_from_object is not None:
            check_rigid(seed_tool_from_object, "seed_tool_from_object")
            prior = se3.invert(np.asarray(seed_tool_from_object, dtype=np.float64))
        elif prm.track and self.last_object_from_tool is not None:
            prior, tracking = self.last_object_from_tool, True

        problem = (
            spread_problem(pts)
            if len(pts) >= prm.min_points
            else (f"{len(pts)} finite points, at least {prm.min_points} needed")
        )
        if problem:
            return FitResult(
                object_from_tool=prior if prior is not None else np.eye(4),
                residual_rms_m=0.0,
                cost=0.0,
                iterations=0,
                status="no_patch",
                solve_secs=time.perf_counter() - start,
                points_used=len(pts),
                solver=self.solver.name,
                seeds_tried=0,
                message=problem,
            )
        # The sensor's noise does not change between frames: measured on a search, kept
        # while tracking.
        kept = self.last_noise_m if tracking else 0.0
        rays = camera_rays(pts, sides)
        noise = prm.noise_m or kept or max(estimate_noise_m(pts, rays), prm.min_noise_m)
        if prior is not None:
            first = self._solve(pts, prior)
            if not prm.search or self._warm_stands(first, prior, tracking, noise):
                judged = self._judge(
                    pts, rays, [_Minimum(first, 0)], first.iterations, 1, True, noise, start
                )
                if judged.status == "ok" or not prm.search:
                    return judged
        minima, iterations, tried = self._search(pts, sides, prior, noise)
        return self._judge(pts, rays, minima, iterations, tried, prior is not None, noise, start)

    def _warm_stands(
        self, first: FitResult, prior: np.ndarray, tracking: bool, noise: float
    ) -> bool:
        """Whether a prior's single solve may stand without a search (if judged ``ok``):
        it fits as the right pose does and did not wander far from the prior."""
        prm = self.params
        if first.status == "failed" or first.residual_rms_m > prm.warm_accept_ratio * noise:
            return False
        if tracking and first.residual_rms_m > prm.track_rise_ratio * self.last_rms_m:
            return False
        angle, _ = pose_difference(self.solver.field, prior, first.object_from_tool)
        return angle <= prm.warm_deg

    def _search(
        self, pts: np.ndarray, sides: np.ndarray | None, prior: np.ndarray | None, noise: float
    ) -> tuple[list[_Minimum], int, int]:
        """Screen the prior, the data seeds and the best minimum's turns on a subsample,
        then polish the best distinct minimum on the full cloud, and up to three more that
        were within four times the ambiguity margin on the subsample (the alternatives
        the judgement compares it with)."""
        prm = self.params
        screen = clean_points(pts, prm.screen_points)
        data = [se3.invert(s) for s in seed_poses(pts, sides)]
        if self._flip_is_symmetry:
            data = data[::2]  # each axis comes with its flip, the same pose here
        seeds = ([prior] if prior is not None else []) + data
        screened: list[_Minimum] = []
        iterations = 0
        for rank, seed in enumerate(seeds[: prm.max_seeds]):
            result = self._solve(screen, seed)
            iterations += result.iterations
            screened.append(_Minimum(result, rank))
        turned = min(screened, key=lambda m: m.result.cost)
        turned_seeds = [
            t
            for t, sym in zip(
                turns(turned.result.object_from_tool, yaw=self.yaw_turns),
                self._turn_is_symmetry,
                strict=True,
            )
            if not sym
        ]
        budget = max(prm.max_seeds - len(screened), 0)
        for seed in turned_seeds[:budget]:
            result = self._solve(screen, seed)
            iterations += result.iterations
            screened.append(_Minimum(result, len(screened)))
        ranked = self._distinct(sorted(screened, key=lambda m: m.result.cost))
        polished = []
        close = 4.0 * prm.ambiguity_ratio * noise**2 * len(screen)
        for m in ranked[:1] + [
            r for r in ranked[1:4] if r.result.cost - ranked[0].result.cost < close
        ]:
            result = (
                self._solve(pts, m.result.object_from_tool)
                if len(screen) < len(pts)
                else (m.result)
            )
            iterations += result.iterations
            polished.append(_Minimum(result, m.rank))
        polished.sort(key=lambda m: m.result.cost)
        return self._distinct(polished), iterations, len(screened)

    def _distinct(self, minima: list[_Minimum]) -> list[_Minimum]:
        """Minima (cheapest first) with those near a cheaper one dropped; a minimum keeps
        the earliest seed rank of those it absorbs."""
        prm = self.params
        kept: list[_Minimum] = []
        for m in minima:
            for k in kept:
                angle, offset = pose_difference(
                    self.solver.field,
                    k.result.object_from_tool,
                    m.result.object_from_tool,
                    k.result.observable,
                )
                if angle < prm.distinct_deg and offset < prm.distinct_m:
                    k.rank = min(k.rank, m.rank)
                    break
            else:
                kept.append(_Minimum(m.result, m.rank))
        return kept

    def _judge(
        self,
        pts: np.ndarray,
        rays: np.ndarray | None,
        minima: list[_Minimum],
        iterations: int,
        tried: int,
        had_prior: bool,
        noise: float,
        start: float,
    ) -> FitResult:
        """The verdict on the best usable minimum (module docstring), with its uncertainty."""
        prm = self.params
        usable = [m for m in minima if m.result.status != "failed"]
        if not usable:
            first = minima[0].result
            return self._finish(first, "failed", first.message, iterations, tried, noise, start)
        best = usable[0]
        result = best.result
        if best.rank != 0 or not had_prior:
            result = self._centre_unobservable(result, pts)
        fld = self.solver.field.resized(**result.dims_m)
        result, unc = self._at_minimum(fld, result, pts, rays)
        reasons = []
        inside = judge.within_tolerance(unc, prm.tolerance_deg, prm.tolerance_m)
        if inside < judge.CONFIDENCE:
            reasons.append(
                f"not determined to {prm.tolerance_deg:g} deg / {1e3 * prm.tolerance_m:g} mm: "
                f"within them with probability {inside:.3f} (the 95% region spans "
                f"{unc.region95_deg:.2f} deg / {1e3 * unc.region95_m:.2f} mm)"
            )
        if unc.step_sigma > prm.step_limit:
            stopped = f" (the solver did not converge: {result.message})"
            reasons.append(
                f"not at the minimum of the fit: a step of {unc.step_sigma:.2f} of the 95% "
                f"region remains after {GAUSS_NEWTON_STEPS} Gauss-Newton steps"
                f"{stopped if result.status == 'not_converged' else ''}"
            )
        accept = prm.accept_ratio * noise
        if result.residual_rms_m > accept:
            reasons.append(
                f"residual {1e3 * result.residual_rms_m:.2f} mm above {1e3 * accept:.2f} mm "
                f"({prm.accept_ratio} x noise {1e3 * noise:.2f} mm)"
            )
        # At the answer moved by the bias the rays predict: the mean residual the noise
        # leaves is predicted at the truth, and the fit's minimum sits off it.
        corrected = _moved(fld, result, se3.exp_se3(unc.correction) @ result.object_from_tool, pts)
        bias = corrected.residual_mean_m - unc.noise_mean_m
        if abs(bias) > self._bias_limit_m(noise, len(pts)):
            reasons.append(
                f"the residuals are biased (mean {1e3 * corrected.residual_mean_m:+.3f} mm, "
                f"{1e3 * unc.noise_mean_m:+.3f} mm of it from the noise along the rays, noise "
                f"{1e3 * noise:.2f} mm): the object may differ from its model in size (fit_dims)"
            )
        seen = sum(unc.observable)
        if seen < prm.min_observable:
            reasons.append(f"only {seen} of 6 directions observable")
        if not had_prior and (flat := flatness_m(pts)) < 2.0 * noise:
            # One flat patch fits any flat face of the object equally well; the search
            # need not find every face, so without a prior it is never trusted.
            reasons.append(
                f"a single flat patch (thickness {1e3 * flat:.2f} mm, within twice the noise) "
                "cannot tell which face it touches without a prior"
            )
        close = [
            m.result.object_from_tool
            for m in usable[1:]
            if (m.result.cost - result.cost) / len(pts) < prm.ambiguity_ratio * noise**2
        ]
        alike, differ = judge.alternatives(
            unc,
            result.object_from_tool,
            close,
            turns=self._turn_labels,
            tolerance_deg=prm.tolerance_deg,
            tolerance_m=prm.tolerance_m,
        )
        reasons += differ
        if reasons:
            status = "suspect"
        else:
            status = "ok" if best.rank == 0 else "recovered"
        result = replace(
            corrected,
            observable=unc.observable,
            covariance=unc.covariance,
            region95_deg=unc.region95_deg,
            region95_m=unc.region95_m,
            alternatives="; ".join(alike),
        )
        return self._finish(result, status, "; ".join(reasons), iterations, tried, noise, start)

    def _at_minimum(
        self, fld: Field, result: FitResult, pts: np.ndarray, rays: np.ndarray | None
    ) -> tuple[FitResult, judge.Uncertainty]:
        """The answer and its uncertainty at the minimum of the fit: a solver that stopped
        short (ICP, a loose tolerance) is taken up to ``GAUSS_NEWTON_STEPS`` steps
        further, each kept if the cost does not rise; the judgement then says whether
        that reached it."""
        prm = self.params
        unc = judge.uncertainty(
            fld, result.object_from_tool, pts, rays_in_tool=rays, floor=prm.observability_floor
        )
        for _ in range(GAUSS_NEWTON_STEPS):
            if unc.step_sigma <= prm.step_limit:
                break
            stepped = _moved(fld, result, se3.exp_se3(unc.step) @ result.object_from_tool, pts)
            if not stepped.cost <= result.cost:
                break
            result = stepped
            unc = judge.uncertainty(
                fld, result.object_from_tool, pts, rays_in_tool=rays, floor=prm.observability_floor
            )
        return result, unc

    def _bias_limit_m(self, noise: float, n: int) -> float:
        limit: float = (self.params.bias_ratio + 2.0 / np.sqrt(max(n, 1))) * noise
        return limit

    def _centre_unobservable(self, result: FitResult, pts: np.ndarray) -> FitResult:
        """Move the pose along its unobservable translations so the patch's centroid
        sits at the object's origin along them (mid-body, not at a cap a turned seed
        happened to reach); kept only if the cost does not rise."""
        unseen = [k for k in range(3) if not result.observable[k]]
        if not unseen:
            return result
        pose = result.object_from_tool.copy()
        centroid = pose[:3, :3] @ pts.mean(axis=0) + pose[:3, 3]
        pose[unseen, 3] -= centroid[unseen]
        moved = _moved(self.solver.field.resized(**result.dims_m), result, pose, pts)
        return moved if moved.cost <= result.cost * (1.0 + 1e-6) + 1e-12 else result

    def _finish(
        self,
        result: FitResult,
        status: str,
        message: str,
        iterations: int,
        tried: int,
        noise: float,
        start: float,
    ) -> FitResult:
        final = replace(
            result,
            status=status,
            message=message,
            iterations=iterations,
            seeds_tried=tried,
            noise_m=noise,
            solve_secs=time.perf_counter() - start,
        )
        if status in ("ok", "recovered"):
            self.last_object_from_tool = final.object_from_tool
            self.last_rms_m = final.residual_rms_m
            self.last_noise_m = noise
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
            residual_mean_m=float(np.mean(r)) if len(r) else 0.0,
            cost=cost,
            iterations=0,
            status="failed",
            solve_secs=time.perf_counter() - start,
            points_used=len(pts),
            solver=self.solver.name,
            message=message,
        )


def _moved(fld: Field, result: FitResult, pose: np.ndarray, pts: np.ndarray) -> FitResult:
    """``result`` at another pose, with the fit's cost, RMS and mean there."""
    r = residuals(fld, pose, pts)
    cost = float(r @ r)
    return replace(
        result,
        object_from_tool=pose,
        cost=cost,
        residual_rms_m=float(np.sqrt(cost / max(len(pts), 1))),
        residual_mean_m=float(np.mean(r)),
    )
