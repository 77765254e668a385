"""Each camera's mount in its finger, refined from the free membrane and grasps of a cylinder.

What is solved (``scipy.optimize.least_squares``, soft-L1 loss): for each camera a small
motion ``E`` of its CAD mount (``finger_from_sensor = CAD @ E``, ``E`` in the camera's own
frame: a rotation vector and a translation), and for each grasp the cylinder's axis (a
point and a direction; its radius is known), such that

* every free-membrane point the camera sees lies on the inflated membrane's rest shape,
  the ellipsoid cap of ``geometry.gripper.BubbleGeometry`` fixed to the finger;
* every contact point of every grasp lies on that grasp's cylinder, both bubbles' points
  placed in the tool frame at the grasp's measured opening.

Why both: contact with an object of unknown pose cannot tell a motion of both cameras
that the objects could share (a common translation, a common turn about the closing
axis), so the free membrane anchors each camera to its finger; the membrane is a body of
revolution about the finger's length axis, so the turn about that axis comes from the
grasps (at several openings and poses, which also fix the rest through the opening's
known motion). The uncertainty of each mount is the Gauss-Newton covariance scaled by the
residuals' variance: a lower bound that assumes the membrane is its CAD shape (a bubble
inflated to another shape biases the mount; docs/devices.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from geometry.gripper import SIDES, GripperGeometry
from geometry.se3 import exp_so3, make_pose


@dataclass(frozen=True)
class Grasp:
    """One grasp of the cylinder: the opening and each bubble's contact points (sensor frame)."""

    width_m: float
    points: Mapping[str, np.ndarray]


@dataclass(frozen=True)
class MountFit:
    """A refined mount, its 1-sigma uncertainty (largest axis), and the correction's size."""

    finger_from_sensor: np.ndarray
    rotation_sigma_deg: float
    translation_sigma_mm: float
    correction_deg: float
    correction_mm: float


@dataclass(frozen=True)
class MountSolution:
    mounts: dict[str, MountFit]
    grasp_rms_mm: float
    membrane_rms_mm: float
    axes: list[tuple[np.ndarray, np.ndarray]]  # per grasp: (point on axis, unit direction), tool


def _motion(x: np.ndarray) -> np.ndarray:
    return make_pose(exp_so3(x[:3]), x[3:6])


def _ellipsoid_distance(points_f: np.ndarray, geometry: GripperGeometry) -> np.ndarray:
    """First-order signed distance of finger-frame points to the rest membrane's ellipsoid."""
    bubble = geometry.bubble
    axes = bubble.semi_axes_m
    centred = points_f + np.array([bubble.center_offset_m, 0.0, 0.0])
    scaled = centred / axes
    s = np.linalg.norm(scaled, axis=1)
    grad = centred / axes**2 / np.maximum(s, 1e-12)[:, None]
    distance: np.ndarray = (s - 1.0) / np.maximum(np.linalg.norm(grad, axis=1), 1e-12)
    return distance


def _initial_axis(points_tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A first cylinder axis: the two patches' mean, their longest principal direction."""
    centre = points_tool.mean(axis=0)
    _, _, vt = np.linalg.svd(points_tool - centre, full_matrices=False)
    axis = vt[0] - vt[0] @ np.array([1.0, 0.0, 0.0]) * np.array([1.0, 0.0, 0.0])
    norm = np.linalg.norm(axis)
    return centre, (axis / norm if norm > 1e-9 else np.array([0.0, 1.0, 0.0]))


def _basis(direction: np.ndarray) -> np.ndarray:
    """Two unit vectors orthogonal to ``direction`` (and to each other)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(direction, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(direction, u)])


def solve_mounts(
    free: Mapping[str, np.ndarray],
    grasps: Sequence[Grasp],
    radius_m: float,
    *,
    geometry: GripperGeometry | None = None,
    cad: Mapping[str, np.ndarray] | None = None,
) -> MountSolution:
    """Refine both cameras' mounts (see the module docstring).

    Args:
        free: per side, free-membrane points in the sensor frame (N, 3).
        grasps: the cylinder grasps (contact points of both bubbles in their sensor frames).
        radius_m: the cylinder's radius.
        geometry: the gripper (the CAD mounts, the membrane, how the fingers move).
        cad: per side, the mount to start from (default: the geometry's CAD mount).

    Raises:
        ValueError: a side without free points, or fewer than 3 grasps with both bubbles.
    """
    geometry = geometry or GripperGeometry()
    start = {s: np.asarray((cad or {}).get(s, geometry.finger_from_sensor()), float) for s in SIDES}
    for side in SIDES:
        if len(free.get(side, ())) < 50:
            raise ValueError(f"calibration: too few free-membrane points of the {side} camera")
    used = [g for g in grasps if all(len(g.points.get(s, ())) >= 20 for s in SIDES)]
    if len(used) < 3:
        raise ValueError(
            f"calibration: {len(used)} grasp(s) with contact on both bubbles; at least 3 needed"
        )
    finger = {(s, g.width_m): geometry.tool_from_finger(s, g.width_m) for g in used for s in SIDES}

    def tool_points(mounts: dict[str, np.ndarray], grasp: Grasp) -> np.ndarray:
        parts = []
        for side in SIDES:
            pose = finger[(side, grasp.width_m)] @ mounts[side]
            parts.append(grasp.points[side] @ pose[:3, :3].T + pose[:3, 3])
        return np.concatenate(parts)

    # Each grasp's axis starts from a fit with the start mounts; its parameters are the
    # axis point's motion across the axis (2) and the direction's tilt (2).
    seeds = [_initial_axis(tool_points(start, g)) for g in used]
    bases = [_basis(a) for _, a in seeds]

    def unpack(x: np.ndarray) -> tuple[dict[str, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
        mounts = {s: start[s] @ _motion(x[6 * i : 6 * i + 6]) for i, s in enumerate(SIDES)}
        axes = []
        for k, ((c0, a0), basis) in enumerate(zip(seeds, bases, strict=True)):
            p = x[12 + 4 * k : 16 + 4 * k]
            direction = a0 + p[2:] @ basis
            axes.append((c0 + p[:2] @ basis, direction / np.linalg.norm(direction)))
        return mounts, axes

    def residuals(x: np.ndarray) -> np.ndarray:
        mounts, axes = unpack(x)
        out = []
        for side in SIDES:
            m = mounts[side]
            out.append(_ellipsoid_distance(free[side] @ m[:3, :3].T + m[:3, 3], geometry))
        for grasp, (centre, direction) in zip(used, axes, strict=True):
            rel = tool_points(mounts, grasp) - centre
            radial = rel - np.outer(rel @ direction, direction)
            out.append(np.linalg.norm(radial, axis=1) - radius_m)
        return np.concatenate(out)

    x0 = np.zeros(12 + 4 * len(used))
    # Each grasp's axis alone first (the start mounts held): a good start for the joint solve.
    axes_only = least_squares(
        lambda p: residuals(np.concatenate([x0[:12], p])), x0[12:], loss="soft_l1", f_scale=0.002
    )
    x0[12:] = axes_only.x
    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=0.002, x_scale="jac")
    x = fit.x
    mounts, axes = unpack(x)
    r = fit.fun
    n_free = sum(len(free[s]) for s in SIDES)
    jac = fit.jac
    dof = max(len(r) - len(x), 1)
    sigma2 = float(r @ r) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * sigma2
    except np.linalg.LinAlgError:
        cov = np.full((len(x), len(x)), np.inf)
    fits = {}
    for i, side in enumerate(SIDES):
        block = np.diag(cov)[6 * i : 6 * i + 6]
        correction = x[6 * i : 6 * i + 6]
        fits[side] = MountFit(
            finger_from_sensor=mounts[side],
            rotation_sigma_deg=float(np.degrees(np.sqrt(block[:3].max()))),
            translation_sigma_mm=float(np.sqrt(block[3:].max()) * 1000.0),
            correction_deg=float(np.degrees(np.linalg.norm(correction[:3]))),
            correction_mm=float(np.linalg.norm(correction[3:]) * 1000.0),
        )
    return MountSolution(
        mounts=fits,
        grasp_rms_mm=float(np.sqrt(np.mean(r[n_free:] ** 2)) * 1000.0),
        membrane_rms_mm=float(np.sqrt(np.mean(r[:n_free] ** 2)) * 1000.0),
        axes=axes,
    )
