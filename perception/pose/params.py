"""The knobs of the robust pose estimator (``estimator.PoseEstimator``), checked when made."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perception.pose.problem import MIN_POINTS


@dataclass(frozen=True, kw_only=True)
class EstimatorParams:
    """Knobs of the robust wrapper.

    Attributes:
        noise_m: the depth noise sigma; 0 (default) estimates it from each cloud
            (``cloud.estimate_noise_m``, the spread about local quadric fits).
        min_noise_m: floor under the estimated noise (a noiseless cloud still has
            model and sampling error).
        accept_ratio: a minimum whose residual RMS exceeds ``accept_ratio * noise`` is
            taken as wrong. The right pose leaves about 1.0-1.25 times the estimated
            noise; the 75-90 degree wrong minima about 2 and more.
        ambiguity_ratio: two distinct minima (further apart than ``distinct_deg`` or
            ``distinct_m``, up to the object's symmetry) whose mean squared residuals
            differ by less than ``ambiguity_ratio * noise^2`` cannot be told apart: the
            answer is ``suspect``.
        distinct_deg, distinct_m: how far apart two minima must be to count as distinct.
        bias_ratio: a mean residual beyond ``(bias_ratio + 2 / sqrt(N)) * noise``
            (either sign; the second term is two standard errors of a mean of N points)
            is ``suspect``: noise along the rays averages out at the right pose (under
            0.05 of the noise on synthetic and simulated clouds of 3000 points or more),
            a model of the wrong size leaves the points on one side (a radius 1 mm off:
            0.1-3 times the noise).
        min_observable: fewer observable directions than this is ``suspect``.
        tolerance_deg, tolerance_m: ``ok`` needs the 95% region within this rotation
            and this displacement of the object's origin (the benches call an answer
            right within 2 degrees and 2 mm).
        step_limit: the Gauss-Newton step left at the answer, as a fraction of the 95%
            region along it, beyond which the answer is not at the minimum of the fit:
            the judgement takes one such step, and ``suspect`` if one still remains.
        observability_floor: information per point (scaled, as the solvers' floors)
            under which the judgement counts a direction unobservable (from the points
            where the field is smooth across the noise: ``judge.uncertainty``).
        warm_deg: a prior's single solve stands only if its answer is within this
            angle of the prior.
        warm_accept_ratio: ... and its residual RMS within this times the noise.
        min_points: below this many finite points there is no estimate.
        max_points: the cloud is subsampled (fixed seed) to at most this many points.
        screen_points: seeds are screened on a subsample of this many points; the best
            minima are then polished on the full cloud.
        max_seeds: at most this many screening solves per estimate.
        track: warm-start from the last accepted estimate.
        track_rise_ratio: a tracking solve also needs its RMS at most this times the
            last accepted one.
    """

    noise_m: float = 0.0
    min_noise_m: float = 0.0002
    accept_ratio: float = 1.5
    ambiguity_ratio: float = 0.05
    distinct_deg: float = 2.0
    distinct_m: float = 0.002
    bias_ratio: float = 0.07
    min_observable: int = 3
    min_points: int = 10
    max_points: int = 10000
    screen_points: int = 500
    max_seeds: int = 16
    track: bool = True
    track_rise_ratio: float = 1.25
    tolerance_deg: float = 2.0
    tolerance_m: float = 0.002
    step_limit: float = 0.5
    observability_floor: float = 1e-4
    warm_deg: float = 10.0
    warm_accept_ratio: float = 1.3

    def __post_init__(self) -> None:
        for name in ("noise_m", "min_noise_m", "ambiguity_ratio", "bias_ratio"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be >= 0, got {value}")
        positive: tuple[str, ...] = (
            "accept_ratio",
            "distinct_deg",
            "distinct_m",
            "track_rise_ratio",
        )
        positive += ("tolerance_deg", "tolerance_m", "step_limit", "observability_floor")
        for name in (*positive, "warm_deg", "warm_accept_ratio"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if self.min_points < MIN_POINTS:
            raise ValueError(
                f"min_points must be >= {MIN_POINTS} (six unknowns), got {self.min_points}"
            )
        if self.max_points < self.min_points:
            raise ValueError(f"max_points must be >= min_points, got {self.max_points}")
        if self.screen_points < self.min_points:
            raise ValueError(f"screen_points must be >= min_points, got {self.screen_points}")
        if self.max_seeds < 1:
            raise ValueError(f"max_seeds must be >= 1, got {self.max_seeds}")
        if not 0 <= self.min_observable <= 6:
            raise ValueError(f"min_observable must be in [0, 6], got {self.min_observable}")
