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
- Compiled once per user, not per process: the NLP's functions are generated as C and
  built into a shared library kept on disk (``jit_cache``: keyed by the source, CasADi
  version, compiler and flags; atomic writes), which IPOPT then loads. ``jit="auto"``
  compiles when a C compiler works and otherwise falls back to CasADi's virtual machine
  (same answer, slower). Only the Gauss-Newton form is compiled: CasADi's exact Hessian
  of the mapped cost is generated unrolled (about 24 MB of C at 10k points) and is run
  on the virtual machine.
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

Dimensions (``fit_dims``, e.g. ``("radius",)``): chosen dimensions of the field
(``Field.dims_m``) join ``theta`` as decision variables bounded to
``1 +- dims_bound_ratio`` of the model's, with a faint prior toward the model
(``dims_prior_weight`` per squared relative change, far below what a millimetre of
misfit costs) so a dimension the patch does not see stays put.

IPOPT's verdict is mapped honestly: ``Solve_Succeeded``, ``Solved_To_Acceptable_Level``
and ``Search_Direction_Becomes_Too_Small`` (converged to the noise floor) are ``ok``;
every other return (iteration or time limit, restoration failure, invalid numbers, ...)
is ``not_converged`` with IPOPT's status in ``message``. Input is checked first
(``problem.check_problem``).
"""

from __future__ import annotations

import functools
import time
from typing import Annotated, Any, Literal, TypeVar, cast

import casadi as ca
import msgspec
import numpy as np
from msgspec import Meta

from geometry import se3
from geometry.fields import Field
from perception.pose import jit_cache
from perception.pose.problem import (
    FitResult,
    characteristic_length,
    check_problem,
    observability,
    residuals_and_jacobian,
    scaled_information,
)


class IpoptParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Knobs of the IPOPT solve."""

    tol: Annotated[float, Meta(gt=0.0, description="IPOPT's ``tol`` (scaled NLP error).")] = 1e-8
    max_iterations: Annotated[int, Meta(ge=1, description="IPOPT's ``max_iter``.")] = 100
    hessian: Annotated[
        Literal["gauss_newton", "exact"], Meta(description="``gauss_newton`` or ``exact``.")
    ] = "gauss_newton"
    jit: Annotated[
        Literal["auto", "on", "off"],
        Meta(
            description=(
                "``auto`` (compile when a C compiler works), ``on`` (required) or ``off``."
            )
        ),
    ] = "auto"
    compiler: Annotated[
        str, Meta(description="the C compiler for ``jit`` (looked up on PATH).")
    ] = "gcc"
    min_bucket: Annotated[int, Meta(ge=8, description="the smallest padded point count.")] = 256
    observability_floor: Annotated[float, Meta(description="as in ``LMParams``.")] = 1e-4
    gauge_weight: Annotated[
        float, Meta(ge=0.0, description="weight of the prior on unobservable directions.")
    ] = 1.0
    fit_dims: Annotated[
        tuple[str, ...],
        Meta(
            description=(
                "dimensions fitted beside the pose: ``radius``, ``height`` (the field's"
                " ``dims_m`` without ``_m``)."
            )
        ),
    ] = ()
    dims_bound_ratio: Annotated[
        float,
        Meta(
            gt=0.0,
            lt=1.0,
            description="a fitted dimension stays within this fraction of the model's.",
        ),
    ] = 0.2
    dims_prior_weight: Annotated[
        float,
        Meta(ge=0.0, description="weight of the faint prior holding a dimension at the model."),
    ] = 1e-6
    cache_dir: Annotated[
        str, Meta(description='where compiled solvers are kept ("" for the per-user default).')
    ] = ""

    def __post_init__(self) -> None:
        if len(set(self.fit_dims)) != len(self.fit_dims):
            raise ValueError(f"fit_dims must not repeat a name, got {list(self.fit_dims)}")


#: IPOPT return statuses that mean a converged solve.
CONVERGED = frozenset(
    {"Solve_Succeeded", "Solved_To_Acceptable_Level", "Search_Direction_Becomes_Too_Small"}
)


def dim_keys(fld: Field, names: tuple[str, ...]) -> tuple[str, ...]:
    """``("radius",)`` -> ``("radius_m",)``, checked against the field's dims."""
    keys = tuple(f"{n}_m" for n in names)
    unknown = [n for n, k in zip(names, keys, strict=True) if k not in fld.dims_m]
    if unknown:
        valid = sorted(k[:-2] for k in fld.dims_m)
        raise ValueError(f"fit_dims: {unknown} not adjustable on this object; valid: {valid}")
    return keys


def jit_available(compiler: str = "gcc") -> bool:
    """Whether CasADi can compile with ``compiler`` here (a trial build, cached)."""
    return jit_cache.jit_available(compiler)


# A CasADi expression of one kind: the rotation is built once of SX, once of MX.
_Sym = TypeVar("_Sym", ca.MX, ca.SX)


def _rotation(q: _Sym) -> _Sym:
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
        keys = dim_keys(fld, prm.fit_dims)
        nx = 7 + len(keys)
        theta = ca.SX.sym("theta", nx)
        p = ca.SX.sym("p", 3)
        w = ca.SX.sym("w")
        dims: dict[str, ca.SX | ca.MX] = {k: theta[7 + i] for i, k in enumerate(keys)}
        # Of SX symbols in, an SX expression out (the field declares either kind).
        phi = cast(ca.SX, fld.casadi_sized(ca.mtimes(_rotation(theta[3:7]), p) + theta[:3], dims))
        grad = ca.gradient(phi, theta)
        point_cost = ca.Function("point_cost", [theta, p, w], [w * phi * phi])
        point_gn = ca.Function("point_gn", [theta, p, w], [w * ca.mtimes(grad, grad.T)])
        # theta (input 0) is shared, not repeated; outputs are summed over the points.
        cost_map = point_cost.map("cost_map", "serial", size, [0], [0])
        gn_map = point_gn.map("gn_map", "serial", size, [0], [0])

        x = ca.MX.sym("x", nx)
        pts = ca.MX.sym("pts", 3, size)
        wts = ca.MX.sym("wts", 1, size)
        theta0 = ca.MX.sym("theta0", nx)
        gauge = ca.MX.sym("gauge", 6, nx)
        inv_n = ca.MX.sym("inv_n")
        params = ca.vertcat(ca.vec(pts), ca.vec(wts), theta0, ca.vec(gauge), inv_n)
        dx = gauge @ (x - theta0)
        # The faint prior on dimensions, in relative units: D = diag(w / d0^2).
        prior = np.zeros(nx)
        for i, k in enumerate(keys):
            prior[7 + i] = prm.dims_prior_weight / fld.dims_m[k] ** 2
        dd = x - theta0
        f = (
            inv_n * cost_map(x, pts, wts)
            + prm.gauge_weight * ca.dot(dx, dx)
            + ca.dot(dd, ca.DM(prior) * dd)
        )
        g = ca.dot(x[3:7], x[3:7])
        opts: dict[str, Any] = {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.tol": prm.tol,
            "ipopt.max_iter": prm.max_iterations,
            "ipopt.sb": "yes",
        }
        nlp = {"x": x, "p": params, "f": f, "g": g}
        if prm.hessian == "gauss_newton":
            lam_f = ca.MX.sym("lam_f")
            lam_g = ca.MX.sym("lam_g")
            hess = lam_f * (
                2.0 * inv_n * gn_map(x, pts, wts)
                + 2.0 * prm.gauge_weight * (gauge.T @ gauge)
                + 2.0 * ca.diag(ca.DM(prior))
            )
            quat = np.zeros(nx)
            quat[3:7] = 1.0
            hess = hess + 2.0 * lam_g * ca.diag(ca.DM(quat))
            opts["hess_lag"] = ca.Function(
                "nlp_hess_l",
                [x, params, lam_f, lam_g],
                [ca.triu(hess)],
                ["x", "p", "lam_f", "lam_g"],
                ["triu_hess_gamma_x_x"],
            )
        self.size = size
        self.keys = keys
        self.solver = ca.nlpsol("pose_ipopt", "ipopt", nlp, opts)
        # The exact Hessian of the mapped cost comes out unrolled (about 24 MB of C for
        # 10k points, growing with N): never compile it; the Gauss-Newton one is a loop.
        if use_jit and prm.hessian == "gauss_newton":
            names = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_grad")
            functions = [self.solver.oracle(), opts["hess_lag"]]
            functions += [self.solver.get_function(n) for n in names]
            lib = jit_cache.library(
                functions,
                name=f"pose_ipopt_{size}",
                compiler=prm.compiler,
                cache_dir=prm.cache_dir or None,
            )
            opts.pop("hess_lag")
            self.solver = ca.nlpsol("pose_ipopt", "ipopt", str(lib), opts)


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
        self.dim_keys = dim_keys(fld, self.params.fit_dims)
        if self.params.jit == "on" and not jit_available(self.params.compiler):
            raise RuntimeError(f"jit='on' but compiler {self.params.compiler!r} does not work")
        self.use_jit = self.params.jit == "on" or (
            self.params.jit == "auto" and jit_available(self.params.compiler)
        )
        self.length_m = characteristic_length(fld)
        self._prepared: frozenset[int] = frozenset()

    def prepare(self, n_points: int) -> None:
        """Build (and compile, or load from the disk cache) the solver for clouds of
        exactly ``n_points`` ahead of time; clouds a little smaller reuse it (padded)."""
        self._prepared = self._prepared | {int(n_points)}
        _compiled(self.field, int(n_points), self.params, self.use_jit)

    def _weak_directions(self, fld: Field, pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Unobservable directions at ``pose``: (6, k) orthonormal, scaled twist coordinates."""
        _, jac = residuals_and_jacobian(fld, pose, pts)
        evals, evecs = np.linalg.eigh(scaled_information(jac, self.length_m))
        return evecs[:, evals < self.params.observability_floor]

    def _solve_once(
        self,
        comp: _Compiled,
        padded: np.ndarray,
        weights: np.ndarray,
        n: int,
        seed: np.ndarray,
        dims: np.ndarray,
        weak: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        model = np.array([self.field.dims_m[k] for k in comp.keys])
        theta0 = np.concatenate([seed[:3, 3], se3.quat_from_matrix(seed[:3, :3]), model])
        start = theta0.copy()
        start[7:] = dims
        scale_inv = np.array([1.0] * 3 + [self.length_m] * 3)  # twist -> scaled twist
        gauge = np.zeros((6, len(theta0)))
        if weak.shape[1]:
            gauge[: weak.shape[1], :7] = weak.T @ (scale_inv[:, None] * _theta_jacobian(seed))
        param = np.concatenate(
            [padded.ravel(order="F"), weights, theta0, gauge.ravel(order="F"), [1.0 / n]]
        )
        ratio = self.params.dims_bound_ratio
        lbx = np.concatenate([np.full(7, -np.inf), model * (1.0 - ratio)])
        ubx = np.concatenate([np.full(7, np.inf), model * (1.0 + ratio)])
        sol = comp.solver(x0=start, p=param, lbg=1.0, ubg=1.0, lbx=lbx, ubx=ubx)
        theta = np.asarray(sol["x"]).ravel()
        pose = se3.pose_from_quat(theta[3:7], theta[:3])
        return pose, np.clip(theta[7:], lbx[7:], ubx[7:]), comp.solver.stats()

    def solve(self, points_in_tool: np.ndarray, object_from_tool: np.ndarray) -> FitResult:
        """Refine ``object_from_tool`` on finite (N, 3) tool-frame points spread in 3-D.

        Raises:
            ValueError: bad points or a seed that is not rigid (``problem.check_problem``).
        """
        start = time.perf_counter()
        prm = self.params
        pts, pose = check_problem(points_in_tool, object_from_tool)
        n = len(pts)
        size = _bucket(n, prm.min_bucket, self._prepared)
        comp = _compiled(self.field, size, prm, self.use_jit)
        padded = np.zeros((3, size))
        padded[:, :n] = pts.T
        weights = np.zeros(size)
        weights[:n] = 1.0
        dims = np.array([self.field.dims_m[k] for k in self.dim_keys])
        fld = self.field
        weak = self._weak_directions(fld, pose, pts)
        iterations = 0
        stats: dict[str, Any] = {}
        # The gauge is fixed where the solve starts; far from the answer the seed's weak
        # directions can differ from the answer's (a 60-degree seed sees the caps), and
        # a prior on a direction the answer needs biases it by degrees. So re-solve from
        # the answer, with its own gauge, until the weak subspace stops changing.
        for _ in range(3):
            pose, dims, stats = self._solve_once(comp, padded, weights, n, pose, dims, weak)
            iterations += int(stats.get("iter_count", 0))
            fld = self.field.resized(**dict(zip(self.dim_keys, dims, strict=True)))
            new_weak = self._weak_directions(fld, pose, pts)
            same = new_weak.shape[1] == weak.shape[1] and (
                weak.shape[1] == 0 or float(np.sum((weak.T @ new_weak) ** 2)) > weak.shape[1] - 1e-3
            )
            weak = new_weak
            if same:
                break
        r, jac = residuals_and_jacobian(fld, pose, pts)
        flags, _, _ = observability(scaled_information(jac, self.length_m), prm.observability_floor)
        cost = float(r @ r)
        verdict = str(stats.get("return_status", ""))
        if not (np.all(np.isfinite(pose)) and np.isfinite(cost)):
            status = "failed"
        elif verdict in CONVERGED:
            status = "ok"
        else:
            status = "not_converged"
        return FitResult(
            object_from_tool=pose,
            residual_rms_m=float(np.sqrt(cost / max(n, 1))),
            residual_mean_m=float(np.mean(r)),
            cost=cost,
            iterations=iterations,
            status=status,
            solve_secs=time.perf_counter() - start,
            points_used=n,
            observable=flags,
            solver=self.name,
            message="" if status == "ok" else f"IPOPT: {verdict}",
            dims_m=dict(zip(self.dim_keys, (float(d) for d in dims), strict=True)),
        )
