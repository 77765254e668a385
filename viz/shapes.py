"""Triangle meshes of the known objects and where the bubble cameras sit.

The pose estimator fits an object's proximity field (``geometry.objects``); to draw it,
each primitive of the field (capped cylinder, frustum, capsule, sphere, box, placed by
``Transformed`` and joined by ``Union``) becomes a closed triangle mesh in the object
frame. Bodies of revolution are their ``(radius, z)`` profile swept about z.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from geometry.fields import Box, CappedCylinder, Capsule, Field, Frustum, Sphere, Transformed, Union
from geometry.gripper import tool_from_sensor
from geometry.objects import NAMES, make
from geometry.se3 import invert
from messages.types import ToFImage, pose_is_known

SEGMENTS = 32  # around the axis of a body of revolution
ARC_STEPS = 6  # per quarter circle of a capsule's or sphere's profile


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: ``vertices`` (N, 3) float32 metres, ``triangles`` (M, 3) uint32."""

    vertices: np.ndarray
    triangles: np.ndarray

    def transformed(self, a_from_b: np.ndarray) -> np.ndarray:
        """The vertices mapped by a 4x4 pose (float64, (N, 3))."""
        v = self.vertices.astype(np.float64)
        return v @ a_from_b[:3, :3].T + a_from_b[:3, 3]


def _revolve(radius_m: np.ndarray, z_m: np.ndarray) -> Mesh:
    """Sweep a profile (radii and heights, bottom to top, ends on the axis) about z."""
    angles = np.linspace(0.0, 2 * np.pi, SEGMENTS, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    rows = len(radius_m)
    xy = radius_m[:, None, None] * ring[None]
    z = np.broadcast_to(z_m[:, None, None], (rows, SEGMENTS, 1))
    vertices = np.concatenate([xy, z], axis=2).reshape(-1, 3)
    tris = []
    for i in range(rows - 1):
        for j in range(SEGMENTS):
            a, b = i * SEGMENTS + j, i * SEGMENTS + (j + 1) % SEGMENTS
            c, d = a + SEGMENTS, b + SEGMENTS
            tris += [(a, b, d), (a, d, c)]
    return Mesh(vertices.astype(np.float32), np.asarray(tris, dtype=np.uint32))


def _arc(
    radius_m: float, z_center_m: float, start: float, stop: float
) -> tuple[list[float], list[float]]:
    t = np.linspace(start, stop, ARC_STEPS + 1)
    return list(radius_m * np.cos(t)), list(z_center_m + radius_m * np.sin(t))


def _box(half_m: np.ndarray) -> Mesh:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
    return Mesh((corners * half_m).astype(np.float32), np.asarray(tris, dtype=np.uint32))


def _primitive(fld: Field) -> Mesh:
    if isinstance(fld, CappedCylinder):
        r, h = fld.radius_m, fld.height_m / 2
        return _revolve(np.array([0.0, r, r, 0.0]), np.array([-h, -h, h, h]))
    if isinstance(fld, Frustum):
        r0, r1, h = fld.radius_bottom_m, fld.radius_top_m, fld.height_m / 2
        return _revolve(np.array([0.0, r0, r1, 0.0]), np.array([-h, -h, h, h]))
    if isinstance(fld, Capsule):
        r, h = fld.radius_m, fld.length_m / 2
        r_lo, z_lo = _arc(r, -h, -np.pi / 2, 0.0)
        r_hi, z_hi = _arc(r, h, 0.0, np.pi / 2)
        return _revolve(np.array(r_lo + r_hi), np.array(z_lo + z_hi))
    if isinstance(fld, Sphere):
        r_s, z_s = _arc(fld.radius_m, 0.0, -np.pi / 2, np.pi / 2)
        return _revolve(np.array(r_s), np.array(z_s))
    if isinstance(fld, Box):
        return _box(np.asarray(fld.half_m, dtype=np.float64))
    raise TypeError(f"no mesh for a {type(fld).__name__} field")


def field_mesh(fld: Field) -> Mesh:
    """A closed mesh of a field's surface (the union of its primitives' meshes)."""
    if isinstance(fld, Transformed):
        child = field_mesh(fld.child)
        return Mesh(child.transformed(fld.parent_from_child).astype(np.float32), child.triangles)
    if isinstance(fld, Union):
        parts = [field_mesh(c) for c in fld.children]
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return Mesh(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate(
                [p.triangles + np.uint32(o) for p, o in zip(parts, offsets, strict=True)]
            ),
        )
    return _primitive(fld)


@functools.cache
def object_mesh(name: str) -> Mesh | None:
    """The mesh of a known object (``geometry.objects`` name or class label), else None."""
    if name not in NAMES:
        return None
    return field_mesh(make(name).field)


def camera_pose(side: str, width_m: float, image: ToFImage | None = None) -> np.ndarray:
    """``side``'s camera in the tool frame: where ``image`` (its newest frame) says it was
    taken (the pose its source placed it at: the scene's or the rig calibration's mount at
    the opening of its stamp, ``geometry.mount``); the CAD mount at ``width_m`` for a
    frame that carries none, or without a frame."""
    if image is not None and pose_is_known(image.tool_from_sensor):
        return np.asarray(image.tool_from_sensor, dtype=np.float64)
    return tool_from_sensor(side, width_m)


def sensor_from_object(
    tool_from_sensor_pose: np.ndarray, tool_from_object: np.ndarray
) -> np.ndarray:
    """Pose of the object in the frame of a camera at ``tool_from_sensor_pose``."""
    return invert(tool_from_sensor_pose) @ tool_from_object
