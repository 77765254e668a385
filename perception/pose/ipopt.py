"""The paper's formulation: CasADi and IPOPT over translation and a unit quaternion.

Unknowns ``theta = (t, q)`` of ``object_from_tool`` (the paper's G X T): 3
translations and a ``(w, x, y, z)`` quaternion, with the equality ``q.q = 1``. Cost
``(1/N) sum_i phi(R(q) p_i + t)^2`` plus a gauge term (below). The paper used SNOPT;
IPOPT is what CasADi ships.

Made fast without changing the answer:

- The cost is a ``map`` (serial) of one per-point SX function over a fixed number of
  points, never an expanded SX graph of 10k points: the generated code is one loop,
  and ``jit`` compiles it in a second or two instead of exhausting the compiler.
- Fixed sizes: the cloud is padded (weight 0) to the next power of two (at least
  ``min_bucket``), and one solver per (field, size, options) is built once and cached,
  so a compiled function serves every patch of that size class.
- ``jit`` needs a C compiler: ``jit="auto"`` uses one when a trial compile succeeds
  and otherwise falls back to CasADi's virtual machine (same answer, slower). Only the
  Gauss-Newton form is compiled: CasADi's exact Hessian of the mapped cost is generated
  unrolled (about 24 MB of C at 10k points) and is run on the virtual machine.
- ``hessian="gauss_newton"``: the Hessian of the Lagrangian is handed to IPOPT as
  ``(2/N) sum w_i J_i^T J_i`` (mapped with a sum reduction) plus the gauge term and
  ``2 lam_g I`` on the quaternion block. It matches the exact Hessian near the optimum
  at a fraction of its cost. ``hessian="exact"`` keeps CasADi's exact one.

Gauge fixing: without it, directions the patch does not constrain (yaw of a body of
revolution, slide along a cylinder seen on its side) are null directions of the Hessian
and IPOPT's inertia correction adds a large regularization at every iteration (the
solve crawls). They are found at the seed from the scaled information matrix (as in
``lm``) and a quadratic prior ``gauge_weight * ||A (theta - theta0)||^2`` holds them at
the seed; ``A`` maps ``theta`` to those directions only, so observable directions are
not biased. A far seed can have other weak directions than the answer (a 60-degree
seed sees the caps): the solve is repeated from its answer, with the answer's gauge,
until the weak subspace stops changing (at most three solves; the repeat is cheap, it
starts converged). Without the repeat, 6 of 100 solves from 60 degrees ended 2-3
degrees off.
"""

from __future__ import annotations

import functools
import os
import shutil
import tempfile
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose.common import (
    FitResult,
    characteristic_length,
    observability,
    residuals_and_jacobian,
    scaled_information,
)


@dataclass(frozen=True, kw_only=True)
class IpoptParams:
    """Knobs of the IPOPT solve.

    Attributes:
        tol: IPOPT's ``tol`` (scaled NLP error).
        max_iterations: IPOPT's ``max_iter``.
        hessian: ``gauss_newton`` or ``exact``.
        jit: ``auto`` (compile when a C compiler works), ``on`` (required) or ``off``.
        compiler: the C compiler for ``jit`` (looked up on PATH).
        min_bucket: the smallest padded point count.
        observability_floor: as in ``LMParams``.
        gauge_weight: weight of the prior on unobservable directions.
    """

    tol: float = 1e-8
    max_iterations: int = 100
    hessian: str = "gauss_newton"
    jit: str = "auto"
    compiler: str = "gcc"
    min_bucket: int = 256
    observability_floor: float = 1e-4
    gauge_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.hessian not in ("gauss_newton", "exact"):
            raise ValueError(f"hessian must be 'gauss_newton' or 'exact', got {self.hessian!r}")
        if self.jit not in ("auto", "on", "off"):
            raise ValueError(f"jit must be 'auto', 'on' or 'off', got {self.jit!r}")
        if not (self.tol > 0.0):
            raise ValueError(f"tol must be > 0, got {self.tol}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.min_bucket < 8:
            raise ValueError(f"min_bucket must be >= 8, got {self.min_bucket}")
        if not (self.gauge_weight >= 0.0):
            raise ValueError(f"gauge_weight must be >= 0, got {self.gauge_weight}")


@functools.cache
def _jit_dir() -> str:
    # Generated sources and objects go here, not into the working directory; CasADi
    # removes its own files after loading them.
    return tempfile.mkdtemp(prefix="pose_ipopt_jit_")


def _jit_options(compiler: str, flags: str) -> dict:
    # ``jit_name`` is the generated C file's path stem: without a directory in it CasADi
    # writes ``jit_tmp*.c`` into the working directory.
    return {
        "jit": True,
        "compiler": "shell",
        "jit_name": "pose",
        "jit_cleanup": True,
        "jit_options": {"compiler": compiler, "flags": [flags], "directory": _jit_dir()},
        "jit_temp_suffix": True,
    }


def _remove_strays() -> None:
    """Delete the copies of our generated C sources that nlpsol's jit leaves in the
    working directory (it writes each source there and in ``directory``; only the latter
    is cleaned). Only files whose unique, suffixed names are in our jit directory go."""
    for name in os.listdir(_jit_dir()):
        if name.startswith("pose") and name.endswith(".c") and os.path.isfile(name):
            os.remove(name)


@functools.cache
def jit_available(compiler: str = "gcc") -> bool:
    """Whether CasADi can jit-compile with ``compiler`` here (a trial build, cached)."""
    if shutil.which(compiler) is None:
        return False
    x = ca.SX.sym("x")
    try:
        f = ca.Function("jit_probe", [x], [x * x], _jit_options(compiler, "-O1"))
        return float(f(3.0)) == 9.0
    except RuntimeError:
        return False


def _rotation(q: ca.MX | ca.SX) -> ca.MX | ca.SX:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def _bucket(n: int, minimum: int, prepared: frozenset[int] = frozenset()) -> int:
    """Padded size for ``n`` points: a prepared size if one fits within 19%, else the
    next of ``minimum * 2^(k/4)`` rounded up to 256 (at most ~19% padding + 255), so a
    handful of compiled sizes serves every cloud."""
    fits = [s for s in prepared if n <= s <= 1.19 * n + 256]
    if fits:
        return min(fits)
    size = float(minimum)
    while size < n:
        size *= 2.0**0.25
    return int(np.ceil(size / 256.0) * 256)


class _Compiled:
    """One IPOPT solver for one field, point count and set of options."""

    def __init__(self, fld: Field, size: int, prm: IpoptParams, use_jit: bool) -> None:
        theta = ca.SX.sym("theta", 7)
        p = ca.SX.sym("p", 3)
        w = ca.SX.sym("w")
        phi = fld.casadi(ca.mtimes(_rotation(theta[3:]), p) + theta[:3])
        grad = ca.gradient(phi, theta)
        point_cost = ca.Function("point_cost", [theta, p, w], [w * phi * phi])
        point_gn = ca.Function("point_gn", [theta, p, w], [w * ca.mtimes(grad, grad.T)])
        # theta (input 0) is shared, not repeated; outputs are summed over the points.
        cost_map = point_cost.map("cost_map", "serial", size, [0], [0])
        gn_map = point_gn.map("gn_map", "serial", size, [0], [0])

        x = ca.MX.sym("x", 7)
        pts = ca.MX.sym("pts", 3, size)
        wts = ca.MX.sym("wts", 1, size)
        theta0 = ca.MX.sym("theta0", 7)
        gauge = ca.MX.sym("gauge", 6, 7)
        inv_n = ca.MX.sym("inv_n")
        params = ca.vertcat(ca.vec(pts), ca.vec(wts), theta0, ca.vec(gauge), inv_n)
        dx = gauge @ (x - theta0)
        f = inv_n * cost_map(x, pts, wts) + prm.gauge_weight * ca.dot(dx, dx)
        g = ca.dot(x[3:], x[3:])
        opts: dict = {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.tol": prm.tol,
            "ipopt.max_iter": prm.max_iterations,
            "ipopt.sb": "yes",
        }
        jit_opts = _jit_options(prm.compiler, "-O2")
        # The exact Hessian of the mapped cost comes out unrolled (about 24 MB of C for
        # 10k points, growing with N): never jit it; the Gauss-Newton one is a 40 kB loop.
        use_jit = use_jit and prm.hessian == "gauss_newton"
        if use_jit:
            opts.update(jit_opts)
        if prm.hessian == "gauss_newton":
            lam_f = ca.MX.sym("lam_f")
            lam_g = ca.MX.sym("lam_g")
            hess = lam_f * (
                2.0 * inv_n * gn_map(x, pts, wts) + 2.0 * prm.gauge_weight * (gauge.T @ gauge)
            )
            hess = hess + ca.diagcat(ca.MX.zeros(3, 3), 2.0 * lam_g * ca.MX.eye(4))
            opts["hess_lag"] = ca.Function(
                "hess_lag",
                [x, params, lam_f, lam_g],
                [ca.triu(hess)],
                ["x", "p", "lam_f", "lam_g"],
                ["triu_hess_gamma_x_x"],
                jit_opts if use_jit else {},
            )
        self.size = size
        self.solver = ca.nlpsol("pose_ipopt", "ipopt", {"x": x, "p": params, "f": f, "g": g}, opts)
        if use_jit:
            _remove_strays()


@functools.lru_cache(maxsize=16)
def _compiled(fld: Field, size: int, prm: IpoptParams, use_jit: bool) -> _Compiled:
    return _Compiled(fld, size, prm, use_jit)


def _theta_jacobian(object_from_tool: np.ndarray) -> np.ndarray:
    """d xi / d theta at ``theta0`` (6 x 7), xi the left twist of ``X X0^-1``.

    ``omega = 2 vec(dq conj(q0))`` for a unit ``q0`` and ``v = dt - omega x t0``.
    """
    q0 = se3.quat_from_matrix(object_from_tool[:3, :3])
    t0 = object_from_tool[:3, 3]
    w0, v0 = q0[0], q0[1:]
    # vec(dq * conj(q0)) = -dw v0 + w0 dv - dv x v0
    d_omega = np.zeros((3, 4))
    d_omega[:, 0] = -v0
    d_omega[:, 1:] = w0 * np.eye(3) + se3.hat(v0)
    d_omega *= 2.0
    jac = np.zeros((6, 7))
    jac[:3, :3] = np.eye(3)
    jac[:3, 3:] = se3.hat(t0) @ d_omega  # -omega x t0 = t0 x omega
    jac[3:, 3:] = d_omega
    return jac


class IpoptSolver:
    """Local solve with CasADi/IPOPT from one seed."""

    name = "ipopt"

    def __init__(self, fld: Field, params: IpoptParams | None = None) -> None:
        self.field = fld
        self.params = params or IpoptParams()
        if self.params.jit == "on" and not jit_available(self.params.compiler):
            raise RuntimeError(f"jit='on' but compiler {self.params.compiler!r} does not work")
        self.use_jit = self.params.jit == "on" or (
            self.params.jit == "auto" and jit_available(self.params.compiler)
        )
        self.length_m = characteristic_length(fld)
        self._prepared: frozenset[int] = frozenset()

    def prepare(self, n_points: int) -> None:
        """Build (and compile) the solver for clouds of exactly ``n_points`` ahead of time;
        clouds a little smaller reuse it (padded)."""
        self._prepared = self._prepared | {int(n_points)}
        _compiled(self.field, int(n_points), self.params, self.use_jit)

    def _weak_directions(self, pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Unobservable directions at ``pose``: (6, k) orthonormal, scaled twist coordinates."""
        _, jac = residuals_and_jacobian(self.field, pose, pts)
        evals, evecs = np.linalg.eigh(scaled_information(jac, self.length_m))
        return evecs[:, evals < self.params.observability_floor]

    def _solve_once(
        self,
        comp: _Compiled,
        padded: np.ndarray,
        weights: np.ndarray,
        n: int,
        seed: np.ndarray,
        weak: np.ndarray,
    ) -> tuple[np.ndarray, dict]:
        theta0 = np.concatenate([seed[:3, 3], se3.quat_from_matrix(seed[:3, :3])])
        scale_inv = np.array([1.0] * 3 + [self.length_m] * 3)  # twist -> scaled twist
        gauge = np.zeros((6, 7))
        if weak.shape[1]:
            gauge[: weak.shape[1]] = weak.T @ (scale_inv[:, None] * _theta_jacobian(seed))
        param = np.concatenate(
            [padded.ravel(order="F"), weights, theta0, gauge.ravel(order="F"), [1.0 / n]]
        )
        sol = comp.solver(x0=theta0, p=param, lbg=1.0, ubg=1.0)
        theta = np.asarray(sol["x"]).ravel()
        return se3.pose_from_quat(theta[3:], theta[:3]), comp.solver.stats()

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult:
        """Refine ``object_from_tool`` on finite (N, 3) tool-frame points (N >= 1)."""
        start = time.perf_counter()
        prm = self.params
        pts = np.asarray(points_in_tool, dtype=np.float64)
        n = len(pts)
        size = _bucket(n, prm.min_bucket, self._prepared)
        comp = _compiled(self.field, size, prm, self.use_jit)
        padded = np.zeros((3, size))
        padded[:, :n] = pts.T
        weights = np.zeros(size)
        weights[:n] = 1.0
        pose = np.asarray(object_from_tool, dtype=np.float64)
        weak = self._weak_directions(pose, pts)
        iterations = 0
        # The gauge is fixed where the solve starts; far from the answer the seed's weak
        # directions can differ from the answer's (a 60-degree seed sees the caps), and
        # a prior on a direction the answer needs biases it by degrees. So re-solve from
        # the answer, with its own gauge, until the weak subspace stops changing.
        for _ in range(3):
            pose, stats = self._solve_once(comp, padded, weights, n, pose, weak)
            iterations += int(stats.get("iter_count", 0))
            new_weak = self._weak_directions(pose, pts)
            same = new_weak.shape[1] == weak.shape[1] and (
                weak.shape[1] == 0 or float(np.sum((weak.T @ new_weak) ** 2)) > weak.shape[1] - 1e-3
            )
            weak = new_weak
            if same:
                break
        r, jac = residuals_and_jacobian(self.field, pose, pts)
        flags, _, _ = observability(scaled_information(jac, self.length_m), prm.observability_floor)
        cost = float(r @ r)
        # IPOPT's own verdict is kept in ``message`` only: it reports success at wrong
        # minima too, and an iteration-capped solve may still be good. The estimator
        # judges by the residual.
        status = "ok" if np.all(np.isfinite(pose)) and np.isfinite(cost) else "failed"
        return FitResult(
            object_from_tool=pose,
            residual_rms_m=float(np.sqrt(cost / max(n, 1))),
            cost=cost,
            iterations=iterations,
            status=status,
            solve_secs=time.perf_counter() - start,
            points_used=n,
            observable=flags,
            solver=self.name,
            message=str(stats.get("return_status", "")),
        )
