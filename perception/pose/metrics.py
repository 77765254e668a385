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

__all__ = ["axis_error_deg", "covered", "observed_error", "offaxis_error_m", "right"]

#: End over end: the turn a patch that cannot tell an object's ends apart allows.
END_OVER_END = se3.rotation_about(np.array([1.0, 0.0, 0.0]), np.pi)


def right(
    fld: Field,
    result: FitResult,
    tool_from_object_true: np.ndarray,
    *,
    angle_deg: float = 2.0,
    offset_m: float = 0.002,
    ends_alike: bool = False,
    points_in_tool: np.ndarray | None = None,
) -> bool:
    """Within ``angle_deg`` and ``offset_m`` of the truth up to the object's symmetry,
    counting only the translations the estimate observes (``symmetry.pose_difference``);
    never for ``no_patch`` and ``failed``. ``ends_alike``: a body of revolution whose
    patch cannot tell its ends apart (a bottle held by its body) is scored by its axis as
    a line and the offset of its origin from it; another object may be end over end.

    With ``points_in_tool`` (the cloud the estimate was made from) the error is that of
    :func:`observed_error`: motion along a direction (rotations included) is not
    counted when neither the estimate nor the patch at the true pose observes it."""
    if result.status in ("no_patch", "failed"):
        return False
    if ends_alike and fld.revolves_about_z:
        est = result.tool_from_object
        return (
            axis_error_deg(est, tool_from_object_true, flip_symmetric=True) < angle_deg
            and offaxis_error_m(est, tool_from_object_true) < offset_m
        )
    if points_in_tool is not None:
        angle, offset = observed_error(
            fld,
            result,
            tool_from_object_true,
            points_in_tool,
            ends_alike=ends_alike,
            tolerance=(angle_deg, offset_m),
        )
    else:
        angle, offset = pose_difference(
            fld, se3.invert(tool_from_object_true), result.object_from_tool, result.observable
        )
    return angle < angle_deg and offset < offset_m


def observed_error(
    fld: Field,
    result: FitResult,
    tool_from_object_true: np.ndarray,
    points_in_tool: np.ndarray,
    *,
    ends_alike: bool = False,
    tolerance: tuple[float, float] = (2.0, 0.002),
) -> tuple[float, float]:
    """The estimate's rotation (degrees) and origin offset (metres) from the truth, up to
    the object's symmetry turns (and end over end with ``ends_alike``), along the
    directions observed: motion along a twist axis is left out when the estimate says it
    does not observe it *and* the patch does not observe it at the true pose either
    (``judge.uncertainty`` on the same points), so a direction the estimate wrongly
    calls unobservable still counts. Of the turns, the one nearest in units of
    ``tolerance`` (degrees, metres)."""
    truth = se3.invert(tool_from_object_true)
    at_truth = judge.uncertainty(fld, truth, points_in_tool).observable
    seen = [i for i in range(6) if at_truth[i] or result.observable[i]]
    length = characteristic_length(fld)
    scale = np.array([1.0] * 3 + [1.0 / length] * 3)
    basis = np.eye(6)[:, seen]
    turns = list(symmetry_rotations(fld)) + ([END_OVER_END] if ends_alike else [])
    best = (np.inf, np.inf)
    for turn in turns:
        coords = judge.difference_along(
            basis, scale, result.object_from_tool, se3.make_pose(turn) @ truth
        )
        twist = (basis @ coords) * scale
        angle = float(np.degrees(np.linalg.norm(twist[3:])))
        offset = float(np.linalg.norm(twist[:3]))
        if max(angle / tolerance[0], offset / tolerance[1]) < max(
            best[0] / tolerance[0], best[1] / tolerance[1]
        ):
            best = (angle, offset)
    return best


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
        turns.append(END_OVER_END)
    return any(
        judge.within_region(
            unc, judge.observed_difference(unc, result.object_from_tool, se3.make_pose(t) @ truth)
        )
        <= 1.0
        for t in turns
    )
