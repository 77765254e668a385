"""The reference membrane's geometry: turning image flow into tangential metres.

The fitted tangent basis is ``t1`` = the sensor's x axis projected onto the tangent
plane, ``n`` = the plane normal pointing away from the camera, ``t2 = n x t1``; for a
camera looking straight at the membrane this is the image's x and y. A given basis is
any right-handed ``t1, t2, n``, such as the tool's y, z and x axes (:func:`tool_basis`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from geometry.camera import PinholeCamera


def tangent_basis(points: np.ndarray) -> np.ndarray:
    """Rows ``t1, t2, n`` of the tangent frame of a plane fitted to ``points`` (n, 3).

    ``n`` points away from the camera; ``t1`` is the sensor x axis projected onto the
    plane; ``t2 = n x t1``. Falls back to the sensor axes when the fit is degenerate.
    """
    identity = np.eye(3)
    if points.shape[0] < 3:
        return identity
    centred = points - points.mean(axis=0)
    cov = centred.T @ centred
    if not np.isfinite(cov).all():
        return identity
    eigvals, eigvecs = np.linalg.eigh(cov)
    if eigvals[1] <= 1e-12 * max(eigvals[2], 1e-30):
        return identity  # collinear points: no plane
    n = eigvecs[:, 0]
    if n[2] < 0:
        n = -n
    t1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    norm = np.linalg.norm(t1)
    if norm < 1e-6:  # the plane's normal is the sensor x axis: use y instead
        t1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
        norm = np.linalg.norm(t1)
    t1 /= norm
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n])


def tool_basis(tool_from_sensor: np.ndarray) -> np.ndarray:
    """Rows: the tool's y, z and x axes in the sensor's camera frame (``t1, t2, n``).

    With this basis ``shear_m`` lies in the plane orthogonal to the grip force (the
    tool's y, z, as the simulator's ground truth) and the torsion is about tool x, for
    both bubbles alike.

    Args:
        tool_from_sensor: the camera's 4x4 pose in the tool frame, as the frame carries
            it (``ToFImage.tool_from_sensor``); only its rotation is used.

    Raises:
        ValueError: when the pose is not a finite 4x4 matrix with a rotation block.
    """
    pose = np.asarray(tool_from_sensor, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ValueError(f"`tool_from_sensor` must be a finite 4x4 pose, got {pose!r}")
    rot = pose[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise ValueError(f"`tool_from_sensor` has no rotation block: {rot!r}")
    return np.array(rot[[1, 2, 0], :])


@dataclass(frozen=True)
class MembraneGeometry:
    """The reference membrane, for turning flow into tangential metres.

    Attributes:
        camera: the camera of the working-resolution images.
        points_m: three flat ``(h * w,)`` float64 arrays, the reference points' x, y, z
            in the sensor frame (NaN where invalid).
        basis: rows ``t1, t2, n`` of the tangent plane fitted to the masked points.
        positions_m: two flat ``(h * w,)`` arrays, the reference points' tangent
            coordinates in metres.
        grid_x, grid_y: float32 pixel coordinate grids ``(h, w)``.
    """

    camera: PinholeCamera
    points_m: tuple[np.ndarray, np.ndarray, np.ndarray]
    basis: np.ndarray
    positions_m: tuple[np.ndarray, np.ndarray]
    grid_x: np.ndarray
    grid_y: np.ndarray

    @classmethod
    def from_depth(
        cls,
        depth_m: np.ndarray,
        mask: np.ndarray,
        camera: PinholeCamera,
        basis: np.ndarray | None = None,
    ) -> MembraneGeometry:
        """Back-project the reference depth; fit the tangent plane unless ``basis`` is given.

        Args:
            depth_m: reference z-depth (NaN invalid).
            mask: the reference mask.
            camera: the camera of these images.
            basis: optional rows ``t1, t2, n`` (orthonormal, right-handed) in the sensor
                frame, e.g. the tool's y, z and x axes: ``shear_m`` is then expressed
                along ``t1`` and ``t2`` and the torsion is about ``n``.
        """
        points = camera.depth_to_points(depth_m).astype(np.float64)
        if basis is None:
            selected = points[mask]
            selected = selected[np.isfinite(selected).all(axis=1)]
            basis = tangent_basis(selected)
        else:
            basis = np.asarray(basis, dtype=np.float64)
            if basis.shape != (3, 3) or not np.allclose(basis @ basis.T, np.eye(3), atol=1e-6):
                raise ValueError(f"`basis` must be a 3x3 orthonormal matrix, got {basis!r}")
            if np.linalg.det(basis) < 0:
                raise ValueError("`basis` must be right-handed (t1 x t2 = n)")
        flat = points.reshape(-1, 3)
        coords = flat @ basis[:2].T
        grid_y, grid_x = np.mgrid[0 : camera.height_px, 0 : camera.width_px].astype(np.float32)
        return cls(
            camera,
            tuple(np.ascontiguousarray(flat[:, i]) for i in range(3)),  # type: ignore[arg-type]
            basis,
            (np.ascontiguousarray(coords[:, 0]), np.ascontiguousarray(coords[:, 1])),
            grid_x,
            grid_y,
        )

    def tangential_displacement_m(
        self, flow: np.ndarray, indices: np.ndarray, depth_cur_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tangential displacement of the dots at the flat pixel ``indices``, in metres.

        The dot of reference pixel ``p`` is now at ``p + flow(p)`` with depth
        ``D_cur(p + flow(p))`` (bilinear); the difference of the two back-projected
        points is projected onto the reference tangent plane.

        Returns:
            ``(s1, s2, d1, d2)``: 1D tangent coordinates of the reference points and
            their tangential displacements (m), for the pixels where all are finite.
        """
        return self.tangential_displacement_full(flow, indices, depth_cur_m)[:4]

    def tangential_displacement_full(
        self, flow: np.ndarray, indices: np.ndarray, depth_cur_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`tangential_displacement_m` plus the flat indices of the pixels kept."""
        map_x = self.grid_x + flow[..., 0]
        map_y = self.grid_y + flow[..., 1]
        # NaN outside the image or next to invalid depth.
        d_cur = cv2.remap(
            depth_cur_m.astype(np.float32, copy=False),
            map_x,
            map_y,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=float("nan"),
        )
        z = d_cur.reshape(-1)[indices].astype(np.float64)
        cam = self.camera
        x = (map_x.reshape(-1)[indices] - cam.cx_px) * (z / cam.fx_px)
        y = (map_y.reshape(-1)[indices] - cam.cy_px) * (z / cam.fy_px)
        rx, ry, rz = (a[indices] for a in self.points_m)
        good = np.isfinite(z) & np.isfinite(rz)
        if not good.all():
            x, y, z, rx, ry, rz = x[good], y[good], z[good], rx[good], ry[good], rz[good]
            indices = indices[good]
        x -= rx
        y -= ry
        z -= rz
        t = self.basis
        d1 = t[0, 0] * x + t[0, 1] * y + t[0, 2] * z
        d2 = t[1, 0] * x + t[1, 1] * y + t[1, 2] * z
        return self.positions_m[0][indices], self.positions_m[1][indices], d1, d2, indices
