"""``pose_estimator.ipopt``, ``.lm`` and ``.icp``: the in-hand object pose from the grasp cloud.

Ports:
    inputs: ``patch`` (ContactPatch), ``grasp`` (GraspState, optional: a release or a
        lost stable grasp drops the tracking state, so the next patch starts cold).
    outputs: ``pose`` (PoseEstimate: ``tool_from_object``, residual RMS, cost,
        iterations, status, solve time, points used, solver, and ``observable`` per
        ``(tx, ty, tz, rx, ry, rz)`` in the object frame).

The solvers estimate the paper's ``G X T`` (``object_from_tool``); the message carries
its inverse, ``tool_from_object``. The node never builds a backlog: ``on_patch`` only
keeps the newest patch (counting the ones it replaces), and a short timer solves it, so
patches that arrived during a solve are skipped in favour of the newest. Statuses are
those of :class:`perception.pose.estimator.PoseEstimator` (``ok``, ``recovered``,
``suspect``, ``no_patch``, ``failed``); bad input never raises and never gives a NaN pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry import objects
from messages.base import Header
from messages.types import ContactPatch, GraspState, PoseEstimate
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.icp import IcpParams, IcpSolver
from perception.pose.ipopt import IpoptParams, IpoptSolver
from perception.pose.lm import LMParams, LMSolver
from runtime.node import Node
from runtime.registry import register


@dataclass(frozen=True, kw_only=True)
class PoseParams:
    """What every pose node takes.

    Attributes:
        object: the object model (``geometry.objects.NAMES``).
        body_only: fit only the object's main body (the paper fits the mug's cylinder);
            otherwise its whole field (mug handle, bottle neck).
        max_points: points kept per patch (subsampled with a fixed seed).
        noise_m, accept_ratio, min_points, max_seeds, track: see ``EstimatorParams``.
        seed_tool_from_object: optional first seed, 16 numbers (row-major 4x4).
        poll_secs: period of the timer that solves the newest patch.
    """

    object: str = "mug"
    body_only: bool = True
    max_points: int = 10000
    noise_m: float = 0.0015
    accept_ratio: float = 1.3
    min_points: int = 10
    max_seeds: int = 14
    track: bool = True
    seed_tool_from_object: list[float] = field(default_factory=list)
    poll_secs: float = 0.001

    def __post_init__(self) -> None:
        if self.object not in objects.NAMES:
            raise ValueError(f"object must be one of {objects.NAMES}, got {self.object!r}")
        if self.seed_tool_from_object and len(self.seed_tool_from_object) != 16:
            raise ValueError(
                f"seed_tool_from_object must have 16 numbers, got {len(self.seed_tool_from_object)}"
            )
        if not (self.poll_secs > 0.0):
            raise ValueError(f"poll_secs must be > 0, got {self.poll_secs}")
        self.estimator_params()  # its own checks, named by field

    def estimator_params(self) -> EstimatorParams:
        return EstimatorParams(
            noise_m=self.noise_m,
            accept_ratio=self.accept_ratio,
            min_points=self.min_points,
            max_points=self.max_points,
            max_seeds=self.max_seeds,
            track=self.track,
        )


@dataclass(frozen=True, kw_only=True)
class IpoptPoseParams(PoseParams):
    """Plus IPOPT's knobs (see ``perception.pose.ipopt.IpoptParams``)."""

    tol: float = 1e-8
    max_iterations: int = 100
    hessian: str = "gauss_newton"
    jit: str = "auto"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.solver_params()

    def solver_params(self) -> IpoptParams:
        return IpoptParams(
            tol=self.tol, max_iterations=self.max_iterations, hessian=self.hessian, jit=self.jit
        )


@dataclass(frozen=True, kw_only=True)
class LMPoseParams(PoseParams):
    """Plus the LM solver's knobs (see ``perception.pose.lm.LMParams``)."""

    cost_tol: float = 1e-8
    max_iterations: int = 60

    def __post_init__(self) -> None:
        super().__post_init__()
        self.solver_params()

    def solver_params(self) -> LMParams:
        return LMParams(cost_tol=self.cost_tol, max_iterations=self.max_iterations)


@dataclass(frozen=True, kw_only=True)
class IcpPoseParams(PoseParams):
    """Plus ICP's knobs (see ``perception.pose.icp.IcpParams``)."""

    max_correspondence_m: float = 0.005
    max_iterations: int = 100

    def __post_init__(self) -> None:
        super().__post_init__()
        self.solver_params()

    def solver_params(self) -> IcpParams:
        return IcpParams(
            max_correspondence_m=self.max_correspondence_m, max_iterations=self.max_iterations
        )


def fit_field(name: str, body_only: bool):  # noqa: ANN201 - a geometry.fields.Field
    """The field to fit: the whole object, or its first (main) body part."""
    model = objects.make(name)
    fld = model.field
    if body_only and hasattr(fld, "children"):
        fld = fld.children[0]
    return model, fld


class _PoseNode(Node):
    inputs = {"patch": ContactPatch, "grasp": GraspState}
    outputs = {"pose": PoseEstimate}
    optional_inputs = frozenset({"grasp"})

    def make_solver(self, fld):  # noqa: ANN001, ANN201 - overridden per implementation
        raise NotImplementedError

    def setup(self) -> None:
        prm = self.params
        _, fld = fit_field(prm.object, prm.body_only)
        self.solver = self.make_solver(fld)
        self.estimator = PoseEstimator(
            self.solver,
            prm.estimator_params(),
            symmetric_about_z=fld.revolves_about_z,
        )
        self.seed = (
            np.asarray(prm.seed_tool_from_object, dtype=np.float64).reshape(4, 4)
            if prm.seed_tool_from_object
            else None
        )
        self.pending: ContactPatch | None = None
        self.skipped = 0
        self.io.add_timer(prm.poll_secs, self._solve_pending)

    def on_patch(self, msg: ContactPatch) -> None:
        if self.pending is not None:
            self.skipped += 1
        self.pending = msg

    def on_grasp(self, msg: GraspState) -> None:
        if msg.event == "released" or not msg.stable:
            self.estimator.reset()

    def _solve_pending(self) -> None:
        msg, self.pending = self.pending, None
        if msg is None:
            return
        seed = self.seed if self.estimator.last_object_from_tool is None else None
        result = self.estimator.estimate(msg.points_in_tool, msg.bubble, seed_tool_from_object=seed)
        self.io.publish(
            "pose",
            PoseEstimate(
                header=Header(stamp_nanos=msg.header.stamp_nanos, frame_id="tool"),
                tool_from_object=np.ascontiguousarray(result.tool_from_object, dtype=np.float64),
                residual_rms_m=float(result.residual_rms_m),
                cost=float(result.cost),
                iterations=int(result.iterations),
                status=result.status,
                solve_secs=float(result.solve_secs),
                points_used=int(result.points_used),
                solver=result.solver,
                observable=[bool(b) for b in result.observable],
            ),
        )


@register("pose_estimator.lm")
class LMPoseNode(_PoseNode):
    """Levenberg-Marquardt on SE(3) (fast path)."""

    Params = LMPoseParams

    def make_solver(self, fld):  # noqa: ANN001, ANN201
        return LMSolver(fld, self.params.solver_params())


@register("pose_estimator.ipopt")
class IpoptPoseNode(_PoseNode):
    """The paper's formulation with CasADi/IPOPT (compiled once for ``max_points``)."""

    Params = IpoptPoseParams

    def make_solver(self, fld):  # noqa: ANN001, ANN201
        solver = IpoptSolver(fld, self.params.solver_params())
        solver.prepare(self.params.max_points)
        return solver


@register("pose_estimator.icp")
class IcpPoseNode(_PoseNode):
    """Point-to-point ICP against the sampled model surface (baseline)."""

    Params = IcpPoseParams

    def make_solver(self, fld):  # noqa: ANN001, ANN201
        return IcpSolver(fld, self.params.solver_params())
