"""SO(3) and SE(3): exp/log maps, quaternions and 4x4 homogeneous helpers (pure numpy).

Conventions, said once for the project: quaternions are ``(w, x, y, z)``, unit norm,
scalar first; poses are 4x4 float64 homogeneous matrices named ``a_from_b`` so that
``p_in_a = a_from_b @ p_in_b``. A twist is ``xi = (v, omega)``: translation part first,
rotation part (axis times angle, radians) second, matching the order
``(tx, ty, tz, rx, ry, rz)`` used by ``PoseEstimate.observable``.

Every function here is finite for every finite input: small-angle branches use Taylor
series, and the log near 180 degrees recovers the axis from the symmetric part.
"""

from __future__ import annotations

import numpy as np

_SMALL_RAD = 1e-6


def hat(w: np.ndarray) -> np.ndarray:
    """The skew matrix ``[w]x`` with ``hat(w) @ v == cross(w, v)``."""
    w = np.asarray(w, dtype=np.float64)
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]], dtype=np.float64)


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (axis times angle, radians)."""
    w = np.asarray(w, dtype=np.float64)
    theta2 = float(w @ w)
    theta = np.sqrt(theta2)
    k = hat(w)
    if theta < _SMALL_RAD:
        a = 1.0 - theta2 / 6.0
        b = 0.5 - theta2 / 24.0
    else:
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / theta2
    return np.eye(3) + a * k + b * (k @ k)


def log_so3(rot: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix, angle in [0, pi]; stable near 0 and pi."""
    rot = np.asarray(rot, dtype=np.float64)
    cos_theta = np.clip((np.trace(rot) - 1.0) * 0.5, -1.0, 1.0)
    theta = float(np.arccos(cos_theta))
    vee = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    if theta < _SMALL_RAD:
        return 0.5 * vee * (1.0 + theta * theta / 6.0)
    if np.pi - theta < 1e-3:
        # sin(theta) ~ 0: the antisymmetric part carries no axis; R + R^T = 2 a a^T (1 - cos)
        # + 2 cos I, so the axis is the column of largest diagonal of the symmetric part.
        sym = 0.5 * (rot + rot.T) - cos_theta * np.eye(3)
        i = int(np.argmax(np.diag(sym)))
        axis = sym[:, i] / np.sqrt(max(sym[i, i], 1e-300))
        axis /= np.linalg.norm(axis)
        if axis @ vee < 0.0:
            axis = -axis
        return axis * theta
    return vee * (theta / (2.0 * np.sin(theta)))


def _left_jacobian_terms(theta2: float) -> tuple[float, float]:
    theta = np.sqrt(theta2)
    if theta < 1e-4:
        return 0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0
    return (1.0 - np.cos(theta)) / theta2, (theta - np.sin(theta)) / (theta2 * theta)


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """4x4 pose of the twist ``xi = (v, omega)``."""
    xi = np.asarray(xi, dtype=np.float64)
    v, w = xi[:3], xi[3:]
    k = hat(w)
    b, c = _left_jacobian_terms(float(w @ w))
    out = np.eye(4)
    out[:3, :3] = exp_so3(w)
    out[:3, 3] = (np.eye(3) + b * k + c * (k @ k)) @ v
    return out


def log_se3(pose: np.ndarray) -> np.ndarray:
    """Twist ``(v, omega)`` of a 4x4 pose (inverse of :func:`exp_se3`)."""
    pose = np.asarray(pose, dtype=np.float64)
    w = log_so3(pose[:3, :3])
    k = hat(w)
    b, c = _left_jacobian_terms(float(w @ w))
    left_jac = np.eye(3) + b * k + c * (k @ k)
    v = np.linalg.solve(left_jac, pose[:3, 3])
    return np.concatenate([v, w])


def make_pose(rot: np.ndarray | None = None, trans: np.ndarray | None = None) -> np.ndarray:
    """4x4 pose from a 3x3 rotation (default identity) and a translation (default zero)."""
    out = np.eye(4)
    if rot is not None:
        out[:3, :3] = rot
    if trans is not None:
        out[:3, 3] = trans
    return out


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (``b_from_a`` from ``a_from_b``), without a general inverse."""
    pose = np.asarray(pose, dtype=np.float64)
    out = np.eye(4)
    rt = pose[:3, :3].T
    out[:3, :3] = rt
    out[:3, 3] = -rt @ pose[:3, 3]
    return out


def transform_points(a_from_b: np.ndarray, points_in_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame b into frame a."""
    pts = np.asarray(points_in_b, dtype=np.float64)
    return pts @ a_from_b[:3, :3].T + a_from_b[:3, 3]


def quat_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` of a rotation matrix, with ``w >= 0``."""
    m = np.asarray(rot, dtype=np.float64)
    tr = np.trace(m)
    # Shepperd's method: divide by the largest of the four candidates, never by ~0.
    cands = [tr, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 1e-300))
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-300))
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 1e-300))
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 1e-300))
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.asarray(q, dtype=np.float64)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0.0 else -out


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion ``(w, x, y, z)`` (normalized first; zero gives I)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        return np.eye(3)
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of two ``(w, x, y, z)`` quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def pose_from_quat(q: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """4x4 pose from a ``(w, x, y, z)`` quaternion and a translation."""
    return make_pose(matrix_from_quat(q), trans)


def rotation_angle(rot: np.ndarray) -> float:
    """Angle (radians, [0, pi]) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(rot) - 1.0) * 0.5, -1.0, 1.0)))


def angle_between(u: np.ndarray, v: np.ndarray) -> float:
    """Angle (radians) between two 3-vectors; 0 if either is zero."""
    nu, nv = np.linalg.norm(u), np.linalg.norm(v)
    if nu < 1e-300 or nv < 1e-300:
        return 0.0
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), float(u @ v)))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly from SO(3)."""
    q = rng.normal(size=4)
    return matrix_from_quat(q)


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation of ``angle_rad`` about ``axis`` (normalized; zero axis gives I)."""
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if n < 1e-300:
        return np.eye(3)
    return exp_so3(axis / n * angle_rad)
