"""How far apart two estimates are up to the object's symmetry: the turns that map a
field onto itself, and the angle and offset between two poses modulo those turns."""

from __future__ import annotations

import functools

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose.problem import characteristic_length


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


@functools.cache
def symmetry_rotations(fld: Field) -> tuple[np.ndarray, ...]:
    """The turns that map the field onto itself among the 24 axis-permuting rotations
    (a box's 90- and 180-degree turns, a cylinder's flip; the identity first), found by
    checking the field on its own surface samples. Yaw of a body of revolution is
    continuous and handled by comparing axes instead (:func:`pose_difference`)."""
    pts = fld.sample_surface(400, np.random.default_rng(7))
    scale = characteristic_length(fld)
    out = []
    for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (2, 1, 0), (1, 0, 2)):
        for signs in np.ndindex(2, 2, 2):
            rot = np.zeros((3, 3))
            rot[np.arange(3), perm] = [1.0 if s == 0 else -1.0 for s in signs]
            if np.linalg.det(rot) < 0.0:
                continue
            if float(np.max(np.abs(fld.value(pts @ rot.T)))) < 1e-6 * scale:
                out.append(rot)
    out.sort(key=lambda r: -float(np.trace(r)))  # the identity first
    return tuple(out)


def pose_difference(
    fld: Field, a: np.ndarray, b: np.ndarray, observable: tuple[bool, ...] = (True,) * 6
) -> tuple[float, float]:
    """How far apart two ``object_from_tool`` estimates are, up to the object's symmetry:
    ``(angle_deg, offset_m)``.

    For a body of revolution the angle is between the axes (as lines when the flip is
    a symmetry) and the offset is that of ``b``'s origin from ``a``'s axis; otherwise
    the smallest rotation angle over the symmetry turns and the distance of the
    origins. Translations along directions ``observable`` marks ``False`` (in ``a``'s
    object frame) are not counted: the patch does not fix them.
    """
    ta, tb = se3.invert(a), se3.invert(b)
    turns = symmetry_rotations(fld)
    # b's origin from a's, in a's object frame, along the observable axes only.
    seen = np.asarray(observable[:3], dtype=np.float64)
    offset = float(np.linalg.norm(seen * (a[:3, :3] @ (tb[:3, 3] - ta[:3, 3]))))
    if not any(observable[3:]):  # a sphere's turns are all invisible
        return 0.0, offset
    if fld.revolves_about_z:
        flip = any(r[2, 2] < 0 for r in turns)
        return (
            axis_error_deg(tb, ta, flip_symmetric=flip),
            offaxis_error_m(tb, ta),
        )
    angle = min(
        float(np.degrees(se3.rotation_angle((ta[:3, :3] @ r).T @ tb[:3, :3]))) for r in turns
    )
    return angle, offset
