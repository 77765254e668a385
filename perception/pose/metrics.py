"""The errors the benches and tests score estimates with, against a known truth."""

from __future__ import annotations

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose import judge
from perception.pose.problem import FitResult, characteristic_length
from perception.pose.symmetry import (
    axis_error_deg,
    offaxis_error_m,
    pose_difference,
    symmetry_rotations,
)

__all__ = ["axis_error_deg", "covered", "offaxis_error_m", "right"]


def right(
    fld: Field,
    result: FitResult,
    tool_from_object_true: np.ndarray,
    *,
    angle_deg: float = 2.0,
    offset_m: float = 0.002,
) -> bool:
    """Within ``angle_deg`` and ``offset_m`` of the truth up to the object's symmetry,
    counting only the translations the estimate observes (``symmetry.pose_difference``);
    never for ``no_patch`` and ``failed``."""
    if result.status in ("no_patch", "failed"):
        return False
    angle, offset = pose_difference(
        fld, se3.invert(tool_from_object_true), result.object_from_tool, result.observable
    )
    return angle < angle_deg and offset < offset_m


def covered(fld: Field, result: FitResult, tool_from_object_true: np.ndarray) -> bool:
    """Whether the truth (up to the object's symmetry turns) lies in the estimate's 95%
    region along the observable directions (``judge``); the covariance is the one the
    estimate carries, its observable directions those the covariance spans."""
    unc = judge.from_covariance(result.covariance, characteristic_length(fld))
    if unc.basis.shape[1] == 0:
        return False
    truth = se3.invert(tool_from_object_true)
    return any(
        judge.within_region(
            unc, judge.observed_difference(unc, result.object_from_tool, se3.make_pose(t) @ truth)
        )
        <= 1.0
        for t in symmetry_rotations(fld)
    )
