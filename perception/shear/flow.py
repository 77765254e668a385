"""Dense flow between two IR frames and its summary: the paper's summed flow.

Pixels count only inside the membrane mask (image border, invalid or out-of-bounds
depth, dark or saturated IR). Image axes: ``x`` right (columns), ``y`` down (rows); a
flow ``(dx, dy)`` in pixels maps a reference pixel to where its dot is now.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from geometry.camera import PinholeCamera
from perception.shear.params import DIS_PRESETS, DisParams, ShearParams


def scaled_camera(camera: PinholeCamera, scale: float, shape: tuple[int, int]) -> PinholeCamera:
    """The camera of an image resized by ``scale`` to ``shape`` (rows, cols).

    Area resizing puts working pixel ``i`` over full-resolution ``(i + 0.5) / s - 0.5``.
    """
    if scale == 1.0:
        return camera
    return PinholeCamera(
        width_px=int(shape[1]),
        height_px=int(shape[0]),
        fx_px=camera.fx_px * scale,
        fy_px=camera.fy_px * scale,
        cx_px=(camera.cx_px + 0.5) * scale - 0.5,
        cy_px=(camera.cy_px + 0.5) * scale - 0.5,
    )


def stretch_ir(ir: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """IR amplitude to 8 bits around mean +- 2 sigma of the valid pixels (docs/facts.md).

    Invalid pixels become mid-grey (128) so that they add no edges for the flow. An image
    without valid pixels, or a flat one (all saturated), becomes uniformly 128.

    Args:
        ir: ``(h, w)`` IR image, any real dtype (uint16 from the camera).
        valid: optional bool mask of the pixels to use; all pixels when None.

    Returns:
        uint8 ``(h, w)`` image.
    """
    values = ir if ir.dtype == np.float32 else ir.astype(np.float32)
    mask_u8 = None
    if valid is not None:
        if not valid.any():
            return np.full(ir.shape, 128, np.uint8)
        mask_u8 = np.ascontiguousarray(valid).view(np.uint8)
    mean, std = cv2.meanStdDev(values, mask=mask_u8)
    mean_v, std_v = float(mean[0, 0]), float(std[0, 0])
    if not (math.isfinite(mean_v) and math.isfinite(std_v) and std_v > 1e-6):
        return np.full(ir.shape, 128, np.uint8)
    gain = 255.0 / (4.0 * std_v)
    out = cv2.convertScaleAbs(values, alpha=gain, beta=128.0 - gain * mean_v)
    if valid is not None:
        out[~valid] = 128
    return out


def resize_for_flow(image: np.ndarray, scale: float) -> np.ndarray:
    """Resize an image for the flow; area averaging (NaN propagates for float depth)."""
    if scale == 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def membrane_mask(
    ir: np.ndarray,
    depth_m: np.ndarray | None,
    params: ShearParams,
) -> np.ndarray:
    """Pixels of one frame that may carry flow: inside the border, valid IR and depth.

    Args:
        ir: ``(h, w)`` IR image.
        depth_m: ``(h, w)`` float depth in metres (NaN invalid) or None (IR only).
        params: thresholds.

    Returns:
        bool ``(h, w)`` mask.
    """
    mask = (ir >= params.min_ir) & (ir < params.saturation_ir)
    if depth_m is not None:
        if depth_m.shape != ir.shape:
            raise ValueError(f"depth shape {depth_m.shape} differs from IR shape {ir.shape}")
        with np.errstate(invalid="ignore"):
            mask &= (depth_m >= params.min_depth_m) & (depth_m <= params.max_depth_m)
    b = params.border_px
    if b > 0:
        mask[:b, :] = False
        mask[-b:, :] = False
        mask[:, :b] = False
        mask[:, -b:] = False
    return mask


def _dis_instance(params: DisParams) -> cv2.DISOpticalFlow:
    dis = cv2.DISOpticalFlow.create(DIS_PRESETS[params.preset])
    if params.finest_scale is not None:
        dis.setFinestScale(params.finest_scale)
    if params.patch_size is not None:
        dis.setPatchSize(params.patch_size)
    if params.patch_stride is not None:
        dis.setPatchStride(params.patch_stride)
    if params.gradient_descent_iterations is not None:
        dis.setGradientDescentIterations(params.gradient_descent_iterations)
    if params.variational_iterations is not None:
        dis.setVariationalRefinementIterations(params.variational_iterations)
    return dis


class DenseFlow:
    """Dense flow from one 8-bit image to another, by the configured method."""

    def __init__(self, params: ShearParams) -> None:
        self.params = params
        self._dis = _dis_instance(params.dis) if params.method == "dis" else None

    def __call__(
        self, ref_u8: np.ndarray, cur_u8: np.ndarray, initial: np.ndarray | None = None
    ) -> np.ndarray:
        """Flow ``(h, w, 2)`` float32 such that ``ref(p) ~ cur(p + flow(p))``."""
        if self._dis is not None:
            if initial is not None:
                # DIS refines a flow passed in with the right size and type.
                flow = self._dis.calc(ref_u8, cur_u8, initial.copy())
            else:
                flow = self._dis.calc(ref_u8, cur_u8, None)  # type: ignore[call-overload]
            return np.asarray(flow)
        fb = self.params.farneback
        flags = cv2.OPTFLOW_FARNEBACK_GAUSSIAN if fb.gaussian_window else 0
        start: np.ndarray | None = None
        if initial is not None:
            flags |= cv2.OPTFLOW_USE_INITIAL_FLOW
            start = initial.copy()
        result = cv2.calcOpticalFlowFarneback(
            ref_u8,
            cur_u8,
            start,  # type: ignore[arg-type]
            fb.pyr_scale,
            fb.levels,
            fb.winsize,
            fb.iterations,
            fb.poly_n,
            fb.poly_sigma,
            flags,
        )
        return np.asarray(result)


def summarize_vectors(
    vectors: np.ndarray, min_magnitude_px: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, bool]:
    """:func:`summarize_flow` of the ``(n, 2)`` flow vectors already selected."""
    if vectors.shape[0] == 0:
        return np.zeros(2), np.zeros(2), 0.0, np.zeros(2), False
    # Column by column: numpy reduces an (n, 2) array along axis 0 slowly.
    total = np.array([vectors[:, 0].sum(dtype=np.float64), vectors[:, 1].sum(dtype=np.float64)])
    mean = total / vectors.shape[0]
    magnitude = float(math.hypot(mean[0], mean[1]))
    if magnitude < max(min_magnitude_px, 1e-12):
        return mean, total, magnitude, np.zeros(2), False
    return mean, total, magnitude, mean / magnitude, True


def summarize_flow(
    flow: np.ndarray, mask: np.ndarray, *, min_magnitude_px: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, bool]:
    """The paper's summed flow and its normalized direction, NaN-free.

    Args:
        flow: ``(h, w, 2)`` displacement field.
        mask: bool ``(h, w)``; only these pixels count. Non-finite flow is ignored too.
        min_magnitude_px: below this mean displacement the direction is undefined.

    Returns:
        ``(mean_px, sum_px, magnitude_px, direction, defined)``; ``direction`` is
        ``(0, 0)`` when not defined.
    """
    vectors = flow.reshape(-1, 2)[np.flatnonzero(mask)]
    if not np.isfinite(vectors).all():
        vectors = vectors[np.isfinite(vectors).all(axis=1)]
    return summarize_vectors(vectors, min_magnitude_px)


def flow_curl(flow: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Finite-difference curl ``d(dy)/dx - d(dx)/dy`` of a flow field.

    NaN outside ``mask`` and on its one-pixel rim, where a difference would straddle
    invalid pixels. For a rigid rotation by ``theta`` the curl is ``2 sin(theta)``.
    """
    dvdx = np.gradient(flow[..., 1].astype(np.float64), axis=1)
    dudy = np.gradient(flow[..., 0].astype(np.float64), axis=0)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    curl = dvdx - dudy
    curl[~inner] = np.nan
    return curl
