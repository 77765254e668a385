"""The knobs of the robust pose estimator (``estimator.PoseEstimator``), checked when made."""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from perception.pose.problem import MIN_POINTS


class EstimatorParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Knobs of the robust wrapper."""

    noise_m: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "the depth noise sigma; 0 (default) estimates it from each cloud "
                "(``cloud.estimate_noise_m``, the spread about local quadric fits)."
            ),
        ),
    ] = 0.0
    min_noise_m: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "floor under the estimated noise (a noiseless cloud still has model and"
                " sampling error)."
            ),
        ),
    ] = 0.0002
    accept_ratio: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "a minimum whose residual RMS exceeds ``accept_ratio * noise`` is taken"
                " as wrong. The right pose leaves about 1.0-1.25 times the estimated "
                "noise; the 75-90 degree wrong minima about 2 and more."
            ),
        ),
    ] = 1.5
    ambiguity_ratio: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "two distinct minima (further apart than ``distinct_deg`` or "
                "``distinct_m``, up to the object's symmetry) whose mean squared "
                "residuals differ by less than ``ambiguity_ratio * noise^2`` cannot be "
                "told apart: the answer is ``suspect``."
            ),
        ),
    ] = 0.05
    distinct_deg: Annotated[
        float, Meta(gt=0, description="how far apart two minima must be to count as distinct.")
    ] = 2.0
    distinct_m: Annotated[
        float, Meta(gt=0, description="how far apart two minima must be to count as distinct.")
    ] = 0.002
    bias_ratio: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "a mean residual beyond the one the noise along the camera rays leaves"
                " at the right pose (``judge.Uncertainty.noise_mean_m``: +0.2 mm at a "
                "box's corner at 3 mm noise) by more than ``(bias_ratio + 2 / sqrt(N))"
                " * noise`` (either sign; the second term is two standard errors of a "
                "mean of N points) is ``suspect``: the prediction is within 0.05 of the"
                " residual RMS on synthetic clouds of 3000 points at 1 and 3 mm, a "
                "model of the wrong size leaves the points on one side (a radius 1 mm "
                "off: 0.1-3 times the noise)."
            ),
        ),
    ] = 0.03
    min_observable: Annotated[
        int, Meta(ge=0, le=6, description="fewer observable directions than this is ``suspect``.")
    ] = 3
    min_points: Annotated[
        int, Meta(ge=MIN_POINTS, description="below this many finite points there is no estimate.")
    ] = 10
    max_points: Annotated[
        int, Meta(description="the cloud is subsampled (fixed seed) to at most this many points.")
    ] = 10000
    screen_points: Annotated[
        int,
        Meta(
            description=(
                "seeds are screened on a subsample of this many points; the best minima"
                " are then polished on the full cloud."
            )
        ),
    ] = 500
    max_seeds: Annotated[
        int, Meta(ge=1, description="at most this many screening solves per estimate.")
    ] = 16
    track: Annotated[bool, Meta(description="warm-start from the last accepted estimate.")] = True
    search: Annotated[
        bool,
        Meta(
            description=(
                "with a prior (a seed or the tracked pose), search the other seeds when "
                "its one solve does not stand (default). False: the prior's one solve is "
                "judged and returned whatever the verdict (``suspect`` stays so, with "
                "its reasons): one solve per estimate, for a fixed cost per frame or "
                "for scoring the judgement of one minimum. A cold start searches always."
            )
        ),
    ] = True
    track_rise_ratio: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "a tracking solve also needs its RMS at most this times the last accepted one."
            ),
        ),
    ] = 1.25
    tolerance_deg: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "``ok`` needs the answer within this rotation and this displacement of"
                " the object's origin with 99.5% probability under its uncertainty (the "
                "benches call an answer right within 2 degrees and 2 mm)."
            ),
        ),
    ] = 2.0
    tolerance_m: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "``ok`` needs the answer within this rotation and this displacement of"
                " the object's origin with 99.5% probability under its uncertainty (the "
                "benches call an answer right within 2 degrees and 2 mm)."
            ),
        ),
    ] = 0.002
    step_limit: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "the Gauss-Newton step left at the answer, as a fraction of the 95% "
                "region along it, beyond which the answer is not at the minimum of the "
                "fit: the judgement takes up to two such steps, and ``suspect`` if one "
                "still remains."
            ),
        ),
    ] = 0.5
    observability_floor: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "information per point (scaled, as the solvers' floors) under which the"
                " judgement counts a direction unobservable (from the points where the "
                "field is smooth across the noise: ``judge.uncertainty``)."
            ),
        ),
    ] = 1e-4
    warm_deg: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "a prior's single solve stands only if its answer is within this angle "
                "of the prior."
            ),
        ),
    ] = 10.0
    warm_accept_ratio: Annotated[
        float, Meta(gt=0, description="... and its residual RMS within this times the noise.")
    ] = 1.3

    def __post_init__(self) -> None:
        if self.max_points < self.min_points:
            raise ValueError(f"max_points must be >= min_points, got {self.max_points}")
        if self.screen_points < self.min_points:
            raise ValueError(f"screen_points must be >= min_points, got {self.screen_points}")
