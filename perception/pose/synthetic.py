"""Synthetic grasp clouds: what two bubbles would see of a known object at a known pose.

For tests and benchmarks without the simulator. The object's surface is sampled
uniformly, moved into the tool frame, and each bubble keeps the part it envelops: the
points within ``depth_m`` of the object's extreme along the closing axis (tool x, see
``geometry.gripper``), inside the bubble's footprint on its plate, and facing the
bubble. Noise is added along each point's ray from its camera (docs/facts.md: about 1 mm at
these ranges). ``bubble`` is 0 for the left finger (at tool +x), 1 for the right.
"""

from __future__ import annotations

import numpy as np

from geometry import se3
from geometry.gripper import DEFAULT_GRIPPER, GripperGeometry
from geometry.objects import ObjectModel


def grasp_cloud(
    model: ObjectModel,
    tool_from_object: np.ndarray,
    *,
    n_points: int,
    noise_m: float,
    rng: np.random.Generator,
    depth_m: float = 0.008,
    gripper: GripperGeometry = DEFAULT_GRIPPER,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample a two-bubble contact cloud of exactly ``n_points`` (fewer if none is seen).

    Returns:
        ``(points_in_tool (n, 3) float64, bubble (n,) uint8)``.
    """
    foot_y, foot_z = gripper.bubble.footprint_semi_axes_m()
    chunks: list[np.ndarray] = []
    sides: list[np.ndarray] = []
    got = 0
    # The extremes along x come from a dense sample once, so every chunk cuts alike.
    probe = se3.transform_points(tool_from_object, model.sample_surface(20000, rng))
    in_foot = (np.abs(probe[:, 1]) < foot_y) & (np.abs(probe[:, 2]) < foot_z)
    if not np.any(in_foot):
        return np.zeros((0, 3)), np.zeros(0, np.uint8)
    x_hi, x_lo = probe[in_foot, 0].max(), probe[in_foot, 0].min()
    rot = tool_from_object[:3, :3]
    sampled = 0
    for _ in range(12):
        if got >= n_points:
            break
        # Size each draw from the acceptance seen so far (a rim contact keeps ~1%).
        rate = max(got / sampled, 1e-3) if sampled else 0.1
        draw = int(min(1.3 * (n_points - got) / rate + 1000, 2_000_000))
        sampled += draw
        obj = model.sample_surface(draw, rng)
        pts = se3.transform_points(tool_from_object, obj)
        _, grad = model.field.value_and_grad(obj)
        normal_x = grad @ rot.T[:, 0]
        foot = (np.abs(pts[:, 1]) < foot_y) & (np.abs(pts[:, 2]) < foot_z)
        left = foot & (pts[:, 0] > x_hi - depth_m) & (normal_x > 0.2)
        right = foot & (pts[:, 0] < x_lo + depth_m) & (normal_x < -0.2)
        for mask, label in ((left, 0), (right, 1)):
            chunks.append(pts[mask])
            sides.append(np.full(int(mask.sum()), label, np.uint8))
            got += int(mask.sum())
    points = np.concatenate(chunks) if chunks else np.zeros((0, 3))
    bubble = np.concatenate(sides) if sides else np.zeros(0, np.uint8)
    keep = rng.permutation(len(points))[:n_points]
    points, bubble = points[keep], bubble[keep]
    if noise_m > 0.0 and len(points):
        # Opening at which both apexes are pressed ``depth_m`` into the object.
        cap, outset = gripper.bubble.cap_height_m, gripper.plate_outset_m
        width = max(x_hi - x_lo + 2.0 * (cap - outset) - 2.0 * depth_m, 0.0)
        for side, k in (("left", 0), ("right", 1)):
            sel = bubble == k
            origin = gripper.tool_from_sensor(side, width)[:3, 3]
            ray = points[sel] - origin
            ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
            points[sel] += ray * rng.normal(scale=noise_m, size=(int(sel.sum()), 1))
    return points, bubble


def random_grasp_pose(
    model: ObjectModel, rng: np.random.Generator, *, tilt_deg: float = 10.0, slide_m: float = 0.015
) -> np.ndarray:
    """A plausible ``tool_from_object`` for a side grasp.

    The object's axis lies in the tool's y-z plane (across the closing axis x) at a
    random angle, tilted out of it by up to ``tilt_deg``; a random yaw about its own
    axis (for an object that is not a body of revolution, the yaw keeps its object x,
    where the mug's handle is, within 30 degrees of across the closing axis, as one
    grasps a mug by its body); its centre slid along the axis by up to ``slide_m``.
    """
    ang = rng.uniform(0.0, 2.0 * np.pi)
    axis = np.array([0.0, np.cos(ang), np.sin(ang)])
    tilt = np.radians(rng.uniform(-tilt_deg, tilt_deg))
    axis = se3.rotation_about(np.cross(axis, [1.0, 0.0, 0.0]), tilt) @ axis
    z = axis / np.linalg.norm(axis)
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.9 else np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    if model.symmetric_about_z:
        yaw = rng.uniform(0, 2 * np.pi)
    else:
        yaw = rng.choice([-0.5, 0.5]) * np.pi + np.radians(rng.uniform(-30.0, 30.0))
    rot = np.stack([x, np.cross(z, x), z], axis=1) @ se3.rotation_about(
        np.array([0.0, 0.0, 1.0]), yaw
    )
    centre = z * rng.uniform(-slide_m, slide_m) + np.array([0.0, 0.0, 0.0])
    return se3.make_pose(rot, centre)


def tilted_seed(
    tool_from_object: np.ndarray,
    tilt_deg: float,
    rng: np.random.Generator,
    *,
    offset_m: float = 0.0,
) -> np.ndarray:
    """The true pose with its axis tilted by exactly ``tilt_deg`` about a random
    direction perpendicular to it, and shifted by ``offset_m`` in a random direction."""
    ang = rng.uniform(0, 2 * np.pi)
    perp_in_object = np.array([np.cos(ang), np.sin(ang), 0.0])
    rot = se3.rotation_about(perp_in_object, np.radians(tilt_deg))
    seed = tool_from_object @ se3.make_pose(rot)
    shift = rng.normal(size=3)
    seed[:3, 3] += offset_m * shift / np.linalg.norm(shift)
    pose: np.ndarray = seed
    return pose
