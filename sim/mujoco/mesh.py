"""The membrane as a triangle mesh: a cap of the rest ellipsoid, rim on the plate.

Built in numpy (no mesher): rings of constant polar angle on the unit sphere cap that
maps onto the ellipsoid cap of ``geometry.gripper.BubbleGeometry``, each ring holding as
many points as its circumference at ``spacing_m`` allows, triangulated by a Delaunay
triangulation of the rings' azimuthal projection (a disc whose hull is the rim). The
last ring lies on the plate (F x = 0): those are the pinned vertices.

Frame F (the finger's plate frame): x along the plate's inward normal, the rim at x = 0.
Triangles are oriented so their normals point out of the bubble (away from the plate).
The material coordinate of a vertex is its rest position projected on the plate (F y,
z): the same coordinates ``sim.tof`` prints the dot pattern in, so a mesh point carries
the dots that lie there on the rest membrane.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from geometry.gripper import BubbleGeometry


@dataclass(frozen=True)
class CapMesh:
    """A cap mesh in F: ``rest_m`` (N, 3), ``triangles`` (M, 3) int, ``pinned`` (N,) bool."""

    rest_m: np.ndarray
    triangles: np.ndarray
    pinned: np.ndarray
    spacing_m: float

    @property
    def material_yz_m(self) -> np.ndarray:
        """Each vertex's material coordinate: its rest (F y, F z), (N, 2)."""
        return self.rest_m[:, 1:]

    @property
    def free(self) -> np.ndarray:
        """Indices of the vertices that move (not on the rim)."""
        return np.flatnonzero(~self.pinned)


def cap_mesh(bubble: BubbleGeometry, spacing_m: float) -> CapMesh:
    """The triangulated rest cap of ``bubble`` with edges about ``spacing_m`` long (cached)."""
    if not (math.isfinite(spacing_m) and 0.0005 <= spacing_m <= 0.03):
        raise ValueError(f"`spacing_m` must be in [0.5, 30] mm, got {spacing_m!r}")
    return _cap_mesh(bubble, float(spacing_m))


@functools.cache
def _cap_mesh(bubble: BubbleGeometry, spacing_m: float) -> CapMesh:
    an, at, al = bubble.semi_axes_m
    c = bubble.center_offset_m
    theta_rim = math.acos(c / an)  # polar angle (from F x) of the rim on the unit sphere
    mean_axis = (an + at + al) / 3.0
    rings = max(2, round(theta_rim * mean_axis / spacing_m))
    thetas = np.linspace(0.0, theta_rim, rings + 1)
    u: list[np.ndarray] = [np.zeros(1)]
    phi: list[np.ndarray] = [np.zeros(1)]
    for k, theta in enumerate(thetas[1:], start=1):
        # Circumference of the ellipsoid's ring, for a count that keeps edges ~spacing.
        a, b = at * math.sin(theta), al * math.sin(theta)
        perimeter = math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))
        n = max(6, round(perimeter / spacing_m))
        offset = 0.5 * (k % 2) * 2 * math.pi / n
        phi.append(offset + np.arange(n) * 2 * math.pi / n)
        u.append(np.full(n, theta))
    theta_all = np.concatenate(u)
    phi_all = np.concatenate(phi)
    # The planar projection (polar angle as radius): its convex hull is the rim ring.
    disc = np.stack([theta_all * np.cos(phi_all), theta_all * np.sin(phi_all)], axis=1)
    triangles = Delaunay(disc).simplices.astype(np.int32)
    x = an * np.cos(theta_all) - c
    y = at * np.sin(theta_all) * np.cos(phi_all)
    z = al * np.sin(theta_all) * np.sin(phi_all)
    pinned = theta_all >= theta_rim - 1e-12
    x[pinned] = 0.0
    rest = np.stack([x, y, z], axis=1)
    # Orient every triangle outwards (its normal has a positive F x on a cap).
    normals = triangle_normals(rest, triangles)
    flip = normals[:, 0] < 0
    triangles[flip] = triangles[flip][:, ::-1]
    # Drop slivers on the rim (three pinned points: no free vertex, no area worth having).
    triangles = triangles[~np.all(pinned[triangles], axis=1)]
    for arr in (rest, triangles, pinned):
        arr.setflags(write=False)
    return CapMesh(rest, np.ascontiguousarray(triangles), pinned, spacing_m)


# A membrane vertex is in contact where the object's field is under the solver's
# residual (m) plus the stand-off of a flat triangle's corners: a triangle touching a
# surface of curvature radius R stands off at its corners by about h^2 / (6 R) for an
# edge h (the circumradius h / sqrt(3) squared over 2 R); R = 30 mm, the radius of the
# objects' grasped bodies (mug 40 mm, PET bottle 33 mm, the wine glass's bowl 22 to 40 mm;
# the square bottle's faces are flatter).
CONTACT_RESIDUAL_M = 0.0005
CONTACT_CURVATURE_RADIUS_M = 0.03


def contact_tolerance_m(spacing_m: float) -> float:
    """How far from the object a vertex of a mesh of edge ``spacing_m`` still touches it."""
    return CONTACT_RESIDUAL_M + spacing_m**2 / (6.0 * CONTACT_CURVATURE_RADIUS_M)


# The shell's reference (stress-free) cap is this fraction of the rest cap's height: the
# air stretches the latex to about the rest cap's 25 mm (measured with the default
# latex, docs/mujoco.md).
REFERENCE_HEIGHT_FRACTION = 0.875


def membrane_mesh(bubble: BubbleGeometry, spacing_m: float) -> CapMesh:
    """The shell's reference mesh for a bubble whose inflated shape is ``bubble``."""
    import dataclasses

    reference = dataclasses.replace(
        bubble, cap_height_m=bubble.cap_height_m * REFERENCE_HEIGHT_FRACTION
    )
    return cap_mesh(reference, spacing_m)


def triangle_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Each triangle's area vector: normal times area (M, 3); outward for a cap mesh."""
    p0, p1, p2 = (points[triangles[:, i]] for i in range(3))
    return 0.5 * np.cross(p1 - p0, p2 - p0)


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (N, 3)."""
    area = triangle_normals(points, triangles)
    acc = np.zeros_like(points)
    for i in range(3):
        np.add.at(acc, triangles[:, i], area)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return acc / np.maximum(norm, 1e-18)


def vertex_area_vectors(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """A third of each adjacent triangle's area vector, summed per vertex (N, 3).

    A uniform pressure ``p`` on the surface pushes vertex ``i`` with ``p`` times this.
    """
    area = triangle_normals(points, triangles) / 3.0
    acc = np.zeros_like(points)
    for i in range(3):
        np.add.at(acc, triangles[:, i], area)
    return acc


def enclosed_volume_m3(points_f: np.ndarray, triangles: np.ndarray) -> float:
    """Volume between the cap and the plate (F x = 0), by the divergence theorem.

    The plate closes the surface; with the origin on the plate its faces add nothing,
    so the volume is the sum of the cap triangles' signed tetrahedra with the origin.
    """
    p0, p1, p2 = (points_f[triangles[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum() / 6.0)
