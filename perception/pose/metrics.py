"""The errors the benches and tests score estimates with, against a known truth."""

from __future__ import annotations

import numpy as np

from geometry import se3


def axis_error_deg(
    tool_from_object_est: np.ndarray, tool_from_object_true: np.ndarray, *, flip_symmetric: bool
) -> float:
    """Angle between the estimated and true object z axes in the tool frame (degrees).

    With ``flip_symmetric`` the axis is a line (a plain cylinder: z and -z look alike).
    """
    a = tool_from_object_est[:3, 2]
    b = tool_from_object_true[:3, 2]
    ang = se3.angle_between(a, b)
    if flip_symmetric:
        ang = min(ang, np.pi - ang)
    return float(np.degrees(ang))


def offaxis_error_m(tool_from_object_est: np.ndarray, tool_from_object_true: np.ndarray) -> float:
    """Distance of the estimated origin from the true axis line (metres, tool frame)."""
    axis = tool_from_object_true[:3, 2]
    d = tool_from_object_est[:3, 3] - tool_from_object_true[:3, 3]
    return float(np.linalg.norm(d - (d @ axis) * axis))
