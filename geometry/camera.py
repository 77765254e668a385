"""Pinhole model of a bubble's internal time-of-flight camera.

Sensor frame (``left_sensor`` / ``right_sensor``): origin at the optical centre, z along
the optical axis, x to the right of the image (increasing column), y down (increasing
row). Pixel centres sit at integer coordinates; ``cx_px = (width_px - 1) / 2`` for a
centred principal point.

Depth images follow docs/design.md: float32 metres, NaN for invalid pixels. The depth of a
pixel is its z coordinate in the sensor frame (as the pico flexx driver's depth image),
not the range along the ray; :meth:`PinholeCamera.range_to_depth` converts.

Defaults come from docs/facts.md: PMD pico flexx class, 224 x 172 pixels, field of view
about 62 x 45 degrees.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, kw_only=True)
class PinholeCamera:
    """Intrinsics of an undistorted pinhole camera.

    Attributes:
        width_px: image columns.
        height_px: image rows.
        fx_px, fy_px: focal lengths in pixels.
        cx_px, cy_px: principal point in pixels (pixel centres at integers).
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if not isinstance(value, int) or value <= 0:
                raise ValueError(f"`{name}` must be a positive integer, got {value!r}")
        for name in ("fx_px", "fy_px"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"`{name}` must be > 0, got {value!r}")
        for name in ("cx_px", "cy_px"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"`{name}` must be finite, got {getattr(self, name)!r}")

    @classmethod
    def from_frame(cls, frame: Any) -> PinholeCamera:
        """The camera a ToF frame message carries (duck-typed, so geometry needs no messages).

        Args:
            frame: anything with ``fx_px``, ``fy_px``, ``cx_px``, ``cy_px`` and ``depth_m``
                and ``ir`` images; the size is that of the depth image, or of the IR image
                when the frame carries no depth.
        """
        image = frame.depth_m if frame.depth_m.size else frame.ir
        height, width = image.shape
        return cls(
            width_px=int(width),
            height_px=int(height),
            fx_px=float(frame.fx_px),
            fy_px=float(frame.fy_px),
            cx_px=float(frame.cx_px),
            cy_px=float(frame.cy_px),
        )

    @classmethod
    def from_fov(
        cls,
        width_px: int = 224,
        height_px: int = 172,
        *,
        hfov_deg: float = 62.0,
        vfov_deg: float = 45.0,
    ) -> PinholeCamera:
        """Intrinsics from resolution and full field of view, principal point centred.

        The field of view spans the outer edges of the outer pixels, so
        ``fx = width / (2 tan(hfov / 2))``.
        """
        for name, value in (("hfov_deg", hfov_deg), ("vfov_deg", vfov_deg)):
            if not 0.0 < value < 180.0:
                raise ValueError(f"`{name}` must be in (0, 180), got {value!r}")
        fx = width_px / (2.0 * math.tan(math.radians(hfov_deg) / 2.0))
        fy = height_px / (2.0 * math.tan(math.radians(vfov_deg) / 2.0))
        return cls(
            width_px=width_px,
            height_px=height_px,
            fx_px=fx,
            fy_px=fy,
            cx_px=(width_px - 1) / 2.0,
            cy_px=(height_px - 1) / 2.0,
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(height_px, width_px)``, the shape of an image."""
        return (self.height_px, self.width_px)

    def rays(self) -> np.ndarray:
        """Per-pixel ray directions with z = 1, shape ``(H, W, 3)`` float64 (cached, read-only).

        A point at depth ``d`` on pixel ``(row, col)`` is ``d * rays()[row, col]``.
        """
        return _rays(self)

    def unit_rays(self) -> np.ndarray:
        """Per-pixel unit ray directions, shape ``(H, W, 3)`` float64 (cached, read-only)."""
        return _unit_rays(self)

    def range_to_depth(self, range_m: np.ndarray) -> np.ndarray:
        """Range along each pixel's ray to z-depth (same shape, NaN stays NaN)."""
        return range_m * self.unit_rays()[..., 2]

    def depth_to_points(self, depth_m: np.ndarray) -> np.ndarray:
        """Back-project a depth image to points in the sensor frame.

        Args:
            depth_m: ``(H, W)`` z-depth in metres; NaN (or non-positive) is invalid.

        Returns:
            ``(H, W, 3)`` float32 points, all three coordinates NaN where invalid.
        """
        depth = np.asarray(depth_m, dtype=np.float32)
        if depth.shape != self.shape:
            raise ValueError(f"depth_m must have shape {self.shape}, got {depth.shape}")
        depth = np.where(depth > 0, depth, np.float32(np.nan))
        return depth[..., None] * self.rays().astype(np.float32)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project sensor-frame points to pixel coordinates ``(u, v)`` = (column, row).

        Args:
            points: ``(..., 3)`` points in the sensor frame.

        Returns:
            ``(..., 2)`` float64 pixel coordinates; NaN for points with z <= 0.
        """
        p = np.asarray(points, dtype=np.float64)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(z > 0, 1.0 / z, np.nan)
        u = self.fx_px * p[..., 0] * inv + self.cx_px
        v = self.fy_px * p[..., 1] * inv + self.cy_px
        return np.stack([u, v], axis=-1)

    def pixel_solid_angle_sr(self) -> np.ndarray:
        """Solid angle each pixel subtends, ``(H, W)`` steradians (cached, read-only)."""
        return _solid_angle(self)


@functools.cache
def _rays(camera: PinholeCamera) -> np.ndarray:
    cols = (np.arange(camera.width_px) - camera.cx_px) / camera.fx_px
    rows = (np.arange(camera.height_px) - camera.cy_px) / camera.fy_px
    x, y = np.meshgrid(cols, rows)
    rays = np.stack([x, y, np.ones_like(x)], axis=-1)
    rays.setflags(write=False)
    return rays


@functools.cache
def _unit_rays(camera: PinholeCamera) -> np.ndarray:
    rays = _rays(camera)
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    unit.setflags(write=False)
    return unit


@functools.cache
def _solid_angle(camera: PinholeCamera) -> np.ndarray:
    # A pixel of area 1/(fx fy) on the z = 1 plane seen at distance |ray| with
    # obliquity cos = 1/|ray|: dOmega = dA cos / |ray|^2 = dA / |ray|^3.
    norm = np.linalg.norm(_rays(camera), axis=-1)
    omega = 1.0 / (camera.fx_px * camera.fy_px * norm**3)
    omega.setflags(write=False)
    return omega
