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
    ends_alike: bool = False,
) -> bool:
    """Within ``angle_deg`` and ``offset_m`` of the truth up to the object's symmetry,
    counting only the translations the estimate observes (``symmetry.pose_difference``);
    never for ``no_patch`` and ``failed``. ``ends_alike``: a body of revolution whose
    patch cannot tell its ends apart (a bottle held by its body) is scored by its axis as
    a line and the offset of its origin from it."""
    if result.status in ("no_patch", "failed"):
        return False
    if ends_alike and fld.revolves_about_z:
        est = result.tool_from_object
        return (
            axis_error_deg(est, tool_from_object_true, flip_symmetric=True) < angle_deg
            and offaxis_error_m(est, tool_from_object_true) < offset_m
        )
    angle, offset = pose_difference(
        fld, se3.invert(tool_from_object_true), result.object_from_tool, result.observable
    )
    return angle < angle_deg and offset < offset_m


def covered(
    fld: Field, result: FitResult, tool_from_object_true: np.ndarray, *, ends_alike: bool = False
) -> bool:
    """Whether the truth (up to the object's symmetry turns, and end over end with
    ``ends_alike``, as in :func:`right`) lies in the estimate's 95% region along the
    observable directions (``judge``); the covariance is the one the estimate carries,
    its observable directions those the covariance spans."""
    unc = judge.from_covariance(result.covariance, characteristic_length(fld))
    if unc.basis.shape[1] == 0:
        return False
    truth = se3.invert(tool_from_object_true)
    turns = list(symmetry_rotations(fld))
    if ends_alike:
        turns.append(se3.rotation_about(np.array([1.0, 0.0, 0.0]), np.pi))
    return any(
        judge.within_region(
            unc, judge.observed_difference(unc, result.object_from_tool, se3.make_pose(t) @ truth)
        )
        <= 1.0
        for t in turns
    )
