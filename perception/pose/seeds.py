"""Starting poses: seeds from the data for a cold start, and the turns of a minimum that
the search checks it against."""

from __future__ import annotations

import numpy as np

from geometry import se3


def frame_from_axis(axis: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """A ``tool_from_object`` whose z is ``axis`` (normalized) at ``centre``; x arbitrary."""
    z = np.asarray(axis, dtype=np.float64)
    z = z / max(float(np.linalg.norm(z)), 1e-300)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return se3.make_pose(np.stack([x, y, z], axis=1), centre)


def seed_poses(points_in_tool: np.ndarray, bubble: np.ndarray | None = None) -> list[np.ndarray]:
    """Starting ``tool_from_object`` poses for a cold start, most likely first.

    The first few come from the data: the object centre is put midway between the two
    bubbles' patch centroids, and the axis along each patch's principal direction (a
    cylinder touches a bubble along a line parallel to its axis), then the other
    in-plane direction. Then the cardinal poses: axis along tool x, y, z. Each axis is
    also tried flipped (top and bottom differ for bottles and glasses).
    """
    pts = np.asarray(points_in_tool, dtype=np.float64)
    if len(pts) == 0:
        return [np.eye(4)]
    groups = [pts]
    if bubble is not None and len(bubble) == len(pts):
        groups = [pts[bubble == k] for k in (0, 1) if np.any(bubble == k)]
    centroids = [g.mean(axis=0) for g in groups if len(g)]
    centre = np.mean(centroids, axis=0)
    axes: list[np.ndarray] = []
    for g in groups:
        if len(g) >= 3:
            centred = g - g.mean(axis=0)
            _, vecs = np.linalg.eigh(centred.T @ centred)  # ascending: principal last
            axes += [vecs[:, 2], vecs[:, 1]]
    axes += [np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])]
    unique: list[np.ndarray] = []
    for a in axes:
        a = a / max(np.linalg.norm(a), 1e-300)
        if all(abs(a @ u) < 0.985 for u in unique):  # 10 degrees apart at least
            unique.append(a)
    seeds = []
    for a in unique:
        seeds.append(frame_from_axis(a, centre))
        seeds.append(frame_from_axis(-a, centre))
    return seeds


def turns(object_from_tool: np.ndarray, *, yaw: bool) -> list[np.ndarray]:
    """The estimate turned 90 degrees both ways about the object's x and y axes, and
    over; with ``yaw``, also about z (objects that are not bodies of revolution)."""
    out = []
    if yaw:
        for angle in (np.pi / 2, -np.pi / 2, np.pi):
            turn = se3.rotation_about(np.array([0.0, 0.0, 1.0]), angle)
            out.append(se3.make_pose(turn) @ object_from_tool)
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        for angle in (np.pi / 2, -np.pi / 2, np.pi):
            if angle == np.pi and axis[1] == 1.0:
                continue  # turning over about x or about y differ by a yaw only
            out.append(se3.make_pose(se3.rotation_about(axis, angle)) @ object_from_tool)
    return out
