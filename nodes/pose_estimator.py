"""``pose_estimator.ipopt``, ``.lm`` and ``.icp``: the in-hand object pose from the grasp cloud.

Ports:
    inputs: ``patch`` (ContactPatch), ``grasp`` (GraspState, optional: see Tracking).
    outputs: ``pose`` (PoseEstimate: ``tool_from_object``, residual RMS, cost,
        iterations, status and the reason in ``message``, solve time, points used,
        solver, the noise measured from the patch, ``observable`` per
        ``(tx, ty, tz, rx, ry, rz)`` in the object frame, the uncertainty (covariance,
        standard deviations, the extent of the 95% region), the alternatives the patch
        cannot tell apart, and the fitted radius and height when
        ``ipopt: {fit_dims: [radius, height]}`` asks for them).

Parameters nest: ``estimator:`` (``EstimatorParams``) and the solver's own, ``ipopt:``,
``lm:`` or ``icp:``, e.g. ``params: {object: mug, estimator: {max_points: 3000},
ipopt: {fit_dims: [radius]}}``.

The solvers estimate the paper's ``G X T`` (``object_from_tool``); the message carries
its inverse, ``tool_from_object``. The node never builds a backlog: ``on_patch`` only
keeps the newest patch (counting the ones it replaces), and a short timer solves it, so
patches that arrived during a solve are skipped in favour of the newest. Statuses are
those of :class:`perception.pose.estimator.PoseEstimator` (``ok``, ``recovered``,
``suspect``, ``no_patch``, ``failed``); bad input never raises and never gives a NaN pose.

Tracking: each estimate is warm-started from the last accepted one, and the estimator
searches its seeds again when the residual says it lost track. With ``grasp``
connected, no track is kept until the grasp is first stable (the partial patch of
closing jaws can fit a wrong minimum within the acceptance); from then on the track is
kept through any grasp state (a jolt can make the grasp monitor report a release for
a moment) until the object was released: the grasp is not stable and the patch has no
usable points (``no_patch``). The next grasp then starts cold again.

Setup: the solver is built (IPOPT: compiled, or loaded from the disk cache). On its
first poll, once the node has said ready, one estimate of a synthetic grasp of the
object is made and forgotten, so the first patch pays for no first call (IPOPT's
libraries, the noise estimate's neighbour search) and the graph's start does not wait
for it (about 0.5 s).
"""

from __future__ import annotations

from typing import Annotated, cast

import msgspec
import numpy as np
from msgspec import Meta

from geometry import objects
from geometry.fields import Field
from messages.base import Header
from messages.types import ContactPatch, GraspState, PoseEstimate, PoseStatus
from perception.pose.estimator import LocalSolver, PoseEstimator
from perception.pose.icp import IcpParams, IcpSolver
from perception.pose.ipopt import IpoptParams, IpoptSolver
from perception.pose.lm import LMParams, LMSolver
from perception.pose.params import EstimatorParams
from perception.pose.problem import check_rigid
from perception.pose.synthetic import grasp_cloud, random_grasp_pose
from runtime.node import Node
from runtime.registry import register


class PoseParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What every pose node takes."""

    object: Annotated[str, Meta(description="the object model (``geometry.objects.NAMES``).")] = (
        "mug"
    )
    body_only: Annotated[
        bool,
        Meta(
            description=(
                "fit only the object's main body (the paper fits the mug's cylinder); "
                "otherwise its whole field (mug handle, bottle neck)."
            )
        ),
    ] = True
    estimator: Annotated[
        EstimatorParams,
        Meta(
            description=(
                "the robust wrapper's knobs (``perception.pose.EstimatorParams``: "
                "``max_points``, ``noise_m``, ``accept_ratio``, ``screen_points``, "
                "...)."
            )
        ),
    ] = msgspec.field(default_factory=EstimatorParams)
    seed_tool_from_object: Annotated[
        list[float], Meta(description="optional first seed, 16 numbers (row-major 4x4, rigid).")
    ] = msgspec.field(default_factory=list)
    poll_secs: Annotated[
        float, Meta(gt=0.0, description="period of the timer that solves the newest patch.")
    ] = 0.001

    def __post_init__(self) -> None:
        if self.object not in objects.NAMES:
            raise ValueError(f"object must be one of {objects.NAMES}, got {self.object!r}")
        if self.seed_tool_from_object:
            if len(self.seed_tool_from_object) != 16:
                raise ValueError(
                    "seed_tool_from_object must have 16 numbers, "
                    f"got {len(self.seed_tool_from_object)}"
                )
            check_rigid(
                np.asarray(self.seed_tool_from_object, dtype=np.float64).reshape(4, 4),
                "seed_tool_from_object",
            )


class IpoptPoseParams(PoseParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Plus IPOPT's knobs, ``ipopt`` (``perception.pose.ipopt.IpoptParams``: ``tol``,
    ``max_iterations``, ``hessian``, ``jit``, ``fit_dims``, ...)."""

    ipopt: IpoptParams = msgspec.field(default_factory=IpoptParams)


class LMPoseParams(PoseParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Plus the LM solver's knobs, ``lm`` (``perception.pose.lm.LMParams``)."""

    lm: LMParams = msgspec.field(default_factory=LMParams)


class IcpPoseParams(PoseParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Plus ICP's knobs, ``icp`` (``perception.pose.icp.IcpParams``)."""

    icp: IcpParams = msgspec.field(default_factory=IcpParams)


def fit_field(name: str, body_only: bool) -> tuple[objects.ObjectModel, Field]:
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

    def make_solver(self, fld: Field) -> LocalSolver:  # overridden per implementation
        raise NotImplementedError

    def setup(self) -> None:
        prm = self.params
        model, fld = fit_field(prm.object, prm.body_only)
        self.solver = self.make_solver(fld)
        self.estimator = PoseEstimator(
            self.solver,
            prm.estimator,
            symmetric_about_z=fld.revolves_about_z,
        )
        self.seed = (
            np.asarray(prm.seed_tool_from_object, dtype=np.float64).reshape(4, 4)
            if prm.seed_tool_from_object
            else None
        )
        self.pending: ContactPatch | None = None
        self.skipped = 0
        # "free": no grasp state seen (track always); "closing": not yet stable (keep no
        # track); "held": stable once (keep the track until the object is released).
        self.grasp_phase = "free"
        self.stable = False
        self.model = model
        self.warmed_up = False
        self.io.add_timer(prm.poll_secs, self._solve_pending)

    def _warm_up(self) -> None:
        """The warm-up (module docstring): a small synthetic grasp, estimated and forgotten
        (small: the first calls are what it is for). It runs on the first poll, once the
        node has said ready, so the graph's start does not wait for it."""
        rng = np.random.default_rng(0)
        points, bubble = grasp_cloud(
            self.model,
            random_grasp_pose(self.model, rng),
            n_points=min(self.params.estimator.screen_points, self.params.estimator.max_points),
            noise_m=0.0005,
            rng=rng,
        )
        self.estimator.estimate(points, bubble)
        self.estimator.reset()
        self.warmed_up = True

    def on_patch(self, msg: ContactPatch) -> None:
        if self.pending is not None:
            self.skipped += 1
        self.pending = msg

    def on_grasp(self, msg: GraspState) -> None:
        self.stable = msg.stable
        if msg.stable:
            self.grasp_phase = "held"
        elif self.grasp_phase != "held":
            self.grasp_phase = "closing"
            self.estimator.reset()

    def _solve_pending(self) -> None:
        if not self.warmed_up:
            self._warm_up()
        msg, self.pending = self.pending, None
        if msg is None:
            return
        seed = self.seed if self.estimator.last_object_from_tool is None else None
        result = self.estimator.estimate(msg.points_in_tool, msg.bubble, seed_tool_from_object=seed)
        released = self.grasp_phase == "held" and not self.stable and result.status == "no_patch"
        if released:
            self.grasp_phase = "closing"
        if self.grasp_phase == "closing":
            self.estimator.reset()
        std = np.sqrt(np.maximum(np.diag(result.covariance), 0.0))
        self.io.publish(
            "pose",
            PoseEstimate(
                header=Header(stamp_nanos=msg.header.stamp_nanos, frame_id="tool"),
                tool_from_object=np.ascontiguousarray(result.tool_from_object, dtype=np.float64),
                residual_rms_m=float(result.residual_rms_m),
                cost=float(result.cost),
                iterations=int(result.iterations),
                # The estimator's final statuses (its _finish) are the message's.
                status=cast(PoseStatus, result.status),
                solve_secs=float(result.solve_secs),
                points_used=int(result.points_used),
                solver=result.solver,
                observable=[bool(b) for b in result.observable],
                message=result.message,
                noise_m=float(result.noise_m),
                fitted_radius_m=float(result.dims_m.get("radius_m", 0.0)),
                fitted_height_m=float(result.dims_m.get("height_m", 0.0)),
                covariance=np.ascontiguousarray(result.covariance, dtype=np.float64),
                translation_std_m=[float(v) for v in std[:3]],
                rotation_std_deg=[float(np.degrees(v)) for v in std[3:]],
                region95_deg=float(result.region95_deg),
                region95_m=float(result.region95_m),
                alternatives=result.alternatives,
            ),
        )


@register("pose_estimator.lm")
class LMPoseNode(_PoseNode):
    """Levenberg-Marquardt on SE(3) (fast path)."""

    Params = LMPoseParams

    def make_solver(self, fld: Field) -> LocalSolver:
        return LMSolver(fld, self.params.lm)


@register("pose_estimator.ipopt")
class IpoptPoseNode(_PoseNode):
    """The paper's formulation with CasADi/IPOPT (compiled for ``max_points`` and
    ``screen_points``, or loaded from the per-user disk cache)."""

    Params = IpoptPoseParams

    def make_solver(self, fld: Field) -> LocalSolver:
        solver = IpoptSolver(fld, self.params.ipopt)
        # The full cloud and the screening subsample: both compiled (or loaded) now.
        solver.prepare(self.params.estimator.max_points)
        solver.prepare(self.params.estimator.screen_points)
        return solver


@register("pose_estimator.icp")
class IcpPoseNode(_PoseNode):
    """Point-to-point ICP against the sampled model surface (baseline)."""

    Params = IcpPoseParams

    def make_solver(self, fld: Field) -> LocalSolver:
        return IcpSolver(fld, self.params.icp)
