"""Levenberg-Marquardt on SE(3) for the proximity fit: exp-map steps, analytic Jacobians.

Minimizes ``sum_i phi(X p_i)^2`` over ``X = object_from_tool`` with left steps
``X <- exp(xi) X`` (see ``problem``). Each iteration: residuals and the analytic
Jacobian ``[g, q x g]`` (vectorized numpy), the 6x6 normal equations scaled so that
rotations are in metres at the object's lever arm, an eigen-split of them, and a damped
step in the observable subspace only. Directions whose information is under
``observability_floor`` (yaw of a body of revolution, translation along a cylinder
seen only on its side) receive no step: they stay at the seed, which is the gauge
fixing, and the result reports them.

Stops when the relative cost decrease falls under ``cost_tol`` (after an accepted
step), when the scaled step falls under ``step_tol_m`` or no damped step decreases the
cost (converged: status ``ok``), or after ``max_iterations`` (status ``not_converged``).
Input is checked first (``problem.check_problem``): finite points spread in 3-D and a
rigid seed, else ``ValueError``.
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from geometry import se3
from geometry.fields import Field
from perception.pose.problem import (
    FitResult,
    characteristic_length,
    check_problem,
    observability,
    residuals_and_jacobian,
    scaled_information,
)


class LMParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Knobs of the LM solver (defaults: converged to well below depth noise)."""

    max_iterations: Annotated[int, Meta(ge=1)] = 60
    cost_tol: Annotated[float, Meta(gt=0)] = 1e-8
    step_tol_m: Annotated[float, Meta(gt=0)] = 1e-8
    observability_floor: Annotated[float, Meta(gt=0)] = 1e-4
    damping_init: Annotated[float, Meta(gt=0)] = 1e-4


class LMSolver:
    """Local LM solve from one seed. Stateless between calls; reuse freely."""

    name = "lm"

    def __init__(self, fld: Field, params: LMParams | None = None) -> None:
        self.field = fld
        self.params = params or LMParams()
        self.length_m = characteristic_length(fld)
        self._scale = np.array([1.0] * 3 + [1.0 / self.length_m] * 3)

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult:
        """Refine ``object_from_tool`` on finite (N, 3) tool-frame points spread in 3-D.

        Raises:
            ValueError: bad points or a seed that is not rigid (``problem.check_problem``).
        """
        start = time.perf_counter()
        prm = self.params
        pts, pose = check_problem(points_in_tool, object_from_tool)
        n = len(pts)
        pose = pose.copy()
        r, jac = residuals_and_jacobian(self.field, pose, pts)
        cost = float(r @ r)
        damping = prm.damping_init
        iterations = 0
        flags: tuple[bool, ...] = (False,) * 6
        converged = False
        for iterations in range(1, prm.max_iterations + 1):  # noqa: B007 - count survives
            info = scaled_information(jac, self.length_m)
            grad_s = (jac * self._scale).T @ r / n
            flags, vecs, vals = observability(info, prm.observability_floor)
            if vals.size == 0:
                converged = True
                break
            proj = vecs.T @ grad_s
            top = float(vals.max())
            accepted = False
            while damping < 1e10:
                step_s = -vecs @ (proj / (vals + damping * top))
                step = step_s * self._scale
                trial = se3.exp_se3(step) @ pose
                # With the Jacobian: most trials are accepted and it is needed next.
                r_trial, jac_trial = residuals_and_jacobian(self.field, trial, pts)
                cost_trial = float(r_trial @ r_trial)
                if np.isfinite(cost_trial) and cost_trial <= cost:
                    accepted = True
                    break
                damping *= 10.0
            if not accepted:
                converged = True  # no damped step decreases the cost
                break
            decrease = cost - cost_trial
            pose, r, jac = trial, r_trial, jac_trial
            cost = cost_trial
            damping = max(damping / 4.0, 1e-12)
            if decrease <= prm.cost_tol * max(cost + decrease, 1e-300) or (
                float(np.linalg.norm(step_s)) < prm.step_tol_m
            ):
                converged = True
                break
        # ``flags`` come from the last linearization, one (converged, tiny) step back.
        return FitResult(
            object_from_tool=pose,
            residual_rms_m=float(np.sqrt(cost / max(n, 1))),
            residual_mean_m=float(np.mean(r)),
            cost=cost,
            iterations=iterations,
            status="ok" if converged else "not_converged",
            solve_secs=time.perf_counter() - start,
            points_used=n,
            observable=flags,
            solver=self.name,
            message="" if converged else f"max_iterations ({prm.max_iterations}) reached",
        )
