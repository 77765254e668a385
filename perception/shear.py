"""Shear of a Soft-bubble membrane from its IR dot pattern (paper, "Shear deformation estimation").

The paper compares two IR images of the printed pseudorandom dot pattern: a reference
taken once the grasp is stable and the latest frame. Dense optical flow (Farneback)
gives a displacement per pixel; their sum, normalized, is the shear direction.

This module does that, and what the paper leaves as future work:

- the flow is Farneback (its parameters are knobs, see :class:`FarnebackParams`) or DIS
  (:class:`DisParams`), optionally on half-resolution input and warm-started from the
  previous frame's flow;
- only pixels of the membrane count: a mask drops the image border (where flow is
  biased), pixels whose depth is invalid (NaN) or outside loose bounds, and IR pixels
  that are dark (invalid) or saturated, in the reference or the current frame;
- ``shear_px`` is the paper's sum divided by the number of masked pixels, i.e. the mean
  displacement in pixels, so that thresholds do not depend on the image size or the
  mask; ``sum_px`` keeps the paper's sum;
- the direction is ``shear_px / |shear_px|`` only when ``|shear_px|`` reaches
  ``min_magnitude_px``; below it, ``direction`` is ``(0, 0)`` and ``direction_defined``
  is ``False`` (never NaN, never an arbitrary unit vector);
- with the depth channel, every tracked dot is back-projected before and after, and its
  3D displacement is projected onto a tangent plane to give ``shear_mm``: the plane
  fitted to the reference membrane, or a given basis such as the tool's y and z axes
  (:func:`tool_basis_in_sensor`, what the node uses);
- the torsion (rotation about the contact normal) is the least-squares rotation of the
  displacement field about its centroid, ``sin(theta) = sum(r x d) / sum(|r|^2)``. For
  an affine field ``d = t + A r`` over a region with isotropic second moments this is
  half the field's curl ``(A21 - A12) / 2``, and for a rigid rotation by ``theta`` it
  is exactly ``sin(theta)``; the least-squares form needs no derivatives of the noisy
  flow or depth (a finite-difference curl is available as :func:`flow_curl`).

Conventions: image axes ``x`` right (columns) and ``y`` down (rows); flow ``(dx, dy)``
in pixels maps a reference pixel to where its dot is now. The fitted tangent basis is
``t1`` = the sensor's x axis projected onto the tangent plane, ``n`` = the plane normal
pointing away from the camera, ``t2 = n x t1``; for a camera looking straight at the
membrane this is the image's x and y. A given basis is any right-handed ``t1, t2, n``.
Positive torsion is a right-handed rotation about ``n`` (without depth: about the
optical axis, in the image from +x towards +y). All values are means over the visible
membrane: the part outside the contact does not move, so they are smaller than the
object's own shift and twist. Depth is z-depth in metres along the optical
axis, NaN where invalid (docs/design.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from geometry.camera import PinholeCamera
from geometry.gripper import DEFAULT_GRIPPER, GripperGeometry

DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
FLOW_METHODS = ("farneback", "dis")


def _require(condition: bool, name: str, value: object, what: str) -> None:
    if not condition:
        raise ValueError(f"`{name}` must be {what}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class FarnebackParams:
    """Farneback's knobs (``cv2.calcOpticalFlowFarneback``).

    Defaults are OpenCV's sample parameters that docs/facts.md cites (pyramid scale 0.5,
    3 levels, window 15, 3 iterations, poly_n 5, sigma 1.2); ``bench/shear.py`` sweeps them.
    """

    pyr_scale: float = 0.5
    levels: int = 3
    winsize: int = 15
    iterations: int = 3
    poly_n: int = 5
    poly_sigma: float = 1.2
    gaussian_window: bool = False

    def __post_init__(self) -> None:
        _require(0.0 < self.pyr_scale < 1.0, "pyr_scale", self.pyr_scale, "in (0, 1)")
        _require(1 <= self.levels <= 10, "levels", self.levels, "in [1, 10]")
        _require(3 <= self.winsize <= 201, "winsize", self.winsize, "in [3, 201]")
        _require(1 <= self.iterations <= 50, "iterations", self.iterations, "in [1, 50]")
        _require(self.poly_n in (5, 7), "poly_n", self.poly_n, "5 or 7")
        _require(0.1 <= self.poly_sigma <= 5.0, "poly_sigma", self.poly_sigma, "in [0.1, 5]")


@dataclass(frozen=True, kw_only=True)
class DisParams:
    """DIS optical flow: a preset and optional overrides (``None`` keeps the preset's)."""

    preset: str = "fast"
    finest_scale: int | None = None
    patch_size: int | None = None
    patch_stride: int | None = None
    gradient_descent_iterations: int | None = None
    variational_iterations: int | None = None

    def __post_init__(self) -> None:
        _require(self.preset in DIS_PRESETS, "preset", self.preset, f"one of {sorted(DIS_PRESETS)}")
        for name, low in (
            ("finest_scale", 0),
            ("patch_size", 2),
            ("patch_stride", 1),
            ("gradient_descent_iterations", 1),
            ("variational_iterations", 0),
        ):
            value = getattr(self, name)
            _require(value is None or value >= low, name, value, f"None or >= {low}")
        if self.patch_size is not None and self.patch_stride is not None:
            _require(
                self.patch_stride <= self.patch_size,
                "patch_stride",
                self.patch_stride,
                f"<= patch_size ({self.patch_size})",
            )


@dataclass(frozen=True, kw_only=True)
class ShearParams:
    """Everything the shear estimate depends on.

    Attributes:
        method: ``"farneback"`` (the paper) or ``"dis"``.
        farneback: Farneback's knobs (used when ``method == "farneback"``).
        dis: DIS's knobs (used when ``method == "dis"``).
        scale: input scale for the flow: 1.0 full resolution, 0.5 half (area averaging).
            Results are always reported in full-resolution pixels.
        warm_start: start each frame's flow from the previous frame's (same reference).
        border_px: full-resolution pixels dropped at each image edge.
        min_depth_m: nearer depth is invalid. The driver already marks pixels outside
            its working range (docs/facts.md: 4-11 cm of *range*) as NaN; z-depth is shorter
            than range off-axis, so these bounds are loose and only catch gross outliers.
        max_depth_m: farther depth is invalid.
        min_ir: IR below this is invalid (the driver reports invalid pixels as 0).
        saturation_ir: IR at or above this is saturated, hence invalid.
        min_magnitude_px: below this mean displacement the direction is undefined.
        min_valid_fraction: below this fraction of masked pixels nothing is defined.
    """

    method: str = "farneback"
    farneback: FarnebackParams = field(default_factory=FarnebackParams)
    dis: DisParams = field(default_factory=DisParams)
    scale: float = 1.0
    warm_start: bool = False
    border_px: int = 4
    min_depth_m: float = 0.01
    max_depth_m: float = 0.5
    min_ir: int = 1
    saturation_ir: int = 65535
    min_magnitude_px: float = 0.05
    min_valid_fraction: float = 0.01

    def __post_init__(self) -> None:
        _require(self.method in FLOW_METHODS, "method", self.method, f"one of {FLOW_METHODS}")
        _require(0.1 <= self.scale <= 1.0, "scale", self.scale, "in [0.1, 1]")
        _require(self.border_px >= 0, "border_px", self.border_px, ">= 0")
        _require(self.min_depth_m >= 0.0, "min_depth_m", self.min_depth_m, ">= 0")
        _require(
            self.max_depth_m > self.min_depth_m,
            "max_depth_m",
            self.max_depth_m,
            f"> min_depth_m ({self.min_depth_m})",
        )
        _require(0 <= self.min_ir <= 65535, "min_ir", self.min_ir, "in [0, 65535]")
        _require(
            self.min_ir < self.saturation_ir <= 65536,
            "saturation_ir",
            self.saturation_ir,
            f"in ({self.min_ir}, 65536]",
        )
        _require(self.min_magnitude_px >= 0.0, "min_magnitude_px", self.min_magnitude_px, ">= 0")
        _require(
            0.0 < self.min_valid_fraction <= 1.0,
            "min_valid_fraction",
            self.min_valid_fraction,
            "in (0, 1]",
        )


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


@dataclass
class ShearResult:
    """One shear estimate; arrays are float64 unless said otherwise.

    Attributes:
        has_reference: False when no reference was set (everything else is zero).
        shear_px: mean displacement over the mask, full-resolution pixels ``(dx, dy)``.
        sum_px: the paper's sum of the flow over the mask (working-resolution pixels
            count, full-resolution displacement).
        magnitude_px: ``|shear_px|``.
        direction: ``shear_px / magnitude_px`` or ``(0, 0)`` when undefined.
        direction_defined: whether ``direction`` means anything.
        shear_mm: mean tangential membrane displacement ``(t1, t2)`` in mm (zero without depth).
        mm_defined: whether ``shear_mm`` and the metric torsion were computed.
        torsion_rad: rotation about the contact normal (metric when ``mm_defined``, else
            in the image plane).
        valid_fraction: fraction of the working image inside the mask.
        flow: the working-resolution flow, float32 ``(h, w, 2)`` in working pixels (or None).
        mask: the working-resolution mask, bool ``(h, w)`` (or None).
    """

    has_reference: bool
    shear_px: np.ndarray
    sum_px: np.ndarray
    magnitude_px: float
    direction: np.ndarray
    direction_defined: bool
    shear_mm: np.ndarray
    mm_defined: bool
    torsion_rad: float
    valid_fraction: float
    flow: np.ndarray | None = None
    mask: np.ndarray | None = None

    @classmethod
    def empty(cls, *, has_reference: bool) -> ShearResult:
        """A finite 'nothing measured' result."""
        return cls(
            has_reference=has_reference,
            shear_px=np.zeros(2),
            sum_px=np.zeros(2),
            magnitude_px=0.0,
            direction=np.zeros(2),
            direction_defined=False,
            shear_mm=np.zeros(2),
            mm_defined=False,
            torsion_rad=0.0,
            valid_fraction=0.0,
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


def _summarize_vectors(
    vectors: np.ndarray, min_magnitude_px: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, bool]:
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
    return _summarize_vectors(vectors, min_magnitude_px)


def rotation_about_centroid(
    x: np.ndarray, y: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[float, bool]:
    """Least-squares rotation angle of a 2D displacement field about its centroid.

    ``sin(theta) = sum(r x d) / sum(|r|^2)`` with ``r`` the positions and ``d`` the
    displacements relative to their means: half the field's curl for an affine field
    over an isotropic region, exactly ``sin(theta)`` for a rigid rotation.

    Args:
        x, y: 1D float64 positions (any unit).
        dx, dy: 1D float64 displacements (same unit).

    Returns:
        ``(theta_rad, defined)``; ``(0.0, False)`` when fewer than 3 points or no spread.
    """
    n = x.shape[0]
    if n < 3:
        return 0.0, False
    sx, sy, sdx, sdy = x.sum(), y.sum(), dx.sum(), dy.sum()
    # Sums of products (BLAS dots), then the centroid terms: one pass over the data.
    spread = float(np.dot(x, x) + np.dot(y, y) - (sx * sx + sy * sy) / n)
    cross = float(np.dot(x, dy) - np.dot(y, dx) - (sx * sdy - sy * sdx) / n)
    if not (math.isfinite(spread) and math.isfinite(cross) and spread > 1e-12 * n):
        return 0.0, False
    sine = cross / spread
    return math.asin(min(1.0, max(-1.0, sine))), True


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


def tool_basis_in_sensor(sensor: str, gripper: GripperGeometry = DEFAULT_GRIPPER) -> np.ndarray:
    """Rows: the tool's y, z and x axes in ``sensor``'s camera frame (``t1, t2, n``).

    With this basis ``shear_mm`` lies in the plane orthogonal to the grip force (the
    tool's y, z, as the simulator's ground truth) and the torsion is about tool x, for
    both bubbles alike.
    """
    # The mount's rotation does not depend on the opening; any width will do.
    tool_from_sensor_rot = gripper.tool_from_sensor(sensor, 0.05)[:3, :3]
    return np.array(tool_from_sensor_rot[[1, 2, 0], :])


@dataclass
class MembraneGeometry:
    """The reference membrane, for turning flow into tangential millimetres.

    Attributes:
        camera: the camera of the working-resolution images.
        points_m: three flat ``(h * w,)`` float64 arrays, the reference points' x, y, z
            in the sensor frame (NaN where invalid).
        basis: rows ``t1, t2, n`` of the tangent plane fitted to the masked points.
        positions_mm: two flat ``(h * w,)`` arrays, the reference points' tangent coordinates.
        grid_x, grid_y: float32 pixel coordinate grids ``(h, w)``.
    """

    camera: PinholeCamera
    points_m: tuple[np.ndarray, np.ndarray, np.ndarray]
    basis: np.ndarray
    positions_mm: tuple[np.ndarray, np.ndarray]
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
                frame, e.g. the tool's y, z and x axes: ``shear_mm`` is then expressed
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
        coords = flat @ basis[:2].T * 1000.0
        grid_y, grid_x = np.mgrid[0 : camera.height_px, 0 : camera.width_px].astype(np.float32)
        return cls(
            camera,
            tuple(np.ascontiguousarray(flat[:, i]) for i in range(3)),  # type: ignore[arg-type]
            basis,
            (np.ascontiguousarray(coords[:, 0]), np.ascontiguousarray(coords[:, 1])),
            grid_x,
            grid_y,
        )

    def tangential_displacement_mm(
        self, flow: np.ndarray, indices: np.ndarray, depth_cur_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tangential displacement of the dots at the flat pixel ``indices``, in millimetres.

        The dot of reference pixel ``p`` is now at ``p + flow(p)`` with depth
        ``D_cur(p + flow(p))`` (bilinear); the difference of the two back-projected
        points is projected onto the reference tangent plane.

        Returns:
            ``(s1, s2, d1, d2)``: 1D tangent coordinates of the reference points and
            their tangential displacements (mm), for the pixels where all are finite.
        """
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
        t = self.basis * 1000.0
        d1 = t[0, 0] * x + t[0, 1] * y + t[0, 2] * z
        d2 = t[1, 0] * x + t[1, 1] * y + t[1, 2] * z
        return self.positions_mm[0][indices], self.positions_mm[1][indices], d1, d2


@dataclass
class _Reference:
    u8: np.ndarray  # working resolution, stretched
    mask: np.ndarray
    geometry: MembraneGeometry | None
    full_shape: tuple[int, int]


class ShearTracker:
    """Shear of one bubble against a reference frame (reference capture, flow, summary).

    Typical use: :meth:`set_reference` once the grasp is stable, :meth:`update` for
    every later frame, :meth:`drop_reference` on release.
    """

    def __init__(self, params: ShearParams | None = None) -> None:
        self.params = params or ShearParams()
        self._flow = DenseFlow(self.params)
        self._ref: _Reference | None = None
        self._last_flow: np.ndarray | None = None

    @property
    def has_reference(self) -> bool:
        return self._ref is not None

    @property
    def reference_shape(self) -> tuple[int, int] | None:
        """``(rows, cols)`` of the reference image, or None without a reference."""
        return None if self._ref is None else self._ref.full_shape

    def drop_reference(self) -> None:
        """Forget the reference; :meth:`update` then reports ``has_reference=False``."""
        self._ref = None
        self._last_flow = None

    def _prepare(
        self, ir: np.ndarray, depth_m: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        if ir.ndim != 2:
            raise ValueError(f"IR must be 2D, got shape {ir.shape}")
        mask = membrane_mask(ir, depth_m, self.params)
        scale = self.params.scale
        if scale != 1.0:
            ir = resize_for_flow(ir.astype(np.float32), scale)
            # A working pixel is valid only when its whole footprint was valid.
            mask = resize_for_flow(mask.view(np.uint8), scale) == 1
            if depth_m is not None:
                depth_m = resize_for_flow(depth_m.astype(np.float32, copy=False), scale)
        return ir, depth_m, mask

    def set_reference(
        self,
        ir: np.ndarray,
        depth_m: np.ndarray | None = None,
        camera: PinholeCamera | None = None,
        basis: np.ndarray | None = None,
    ) -> None:
        """Take this frame as the reference.

        Args:
            ir: ``(h, w)`` IR amplitude.
            depth_m: optional ``(h, w)`` z-depth (NaN invalid), for the mask and the mm output.
            camera: the full-resolution camera; with ``depth_m``, enables ``shear_mm``.
            basis: optional tangent frame for ``shear_mm`` and the torsion (rows
                ``t1, t2, n`` in the sensor frame); None fits the membrane's plane.
        """
        work_ir, work_depth, mask = self._prepare(ir, depth_m)
        geometry = None
        if work_depth is not None and camera is not None:
            if camera.shape != ir.shape:
                raise ValueError(f"camera shape {camera.shape} differs from IR shape {ir.shape}")
            work_camera = scaled_camera(camera, self.params.scale, mask.shape)
            geometry = MembraneGeometry.from_depth(work_depth, mask, work_camera, basis)
        self._ref = _Reference(
            u8=stretch_ir(work_ir, mask),
            mask=mask,
            geometry=geometry,
            full_shape=(int(ir.shape[0]), int(ir.shape[1])),
        )
        self._last_flow = None

    def update(
        self,
        ir: np.ndarray,
        depth_m: np.ndarray | None = None,
        *,
        keep_fields: bool = False,
    ) -> ShearResult:
        """Shear of this frame against the reference.

        Args:
            ir: ``(h, w)`` IR amplitude, same shape as the reference.
            depth_m: optional z-depth (NaN invalid); used for the mask, and for
                ``shear_mm`` when the reference had depth and a camera.
            keep_fields: also return the flow and mask (for overlays).

        Returns:
            A finite :class:`ShearResult`; ``has_reference=False`` without a reference.
        """
        ref = self._ref
        if ref is None:
            return ShearResult.empty(has_reference=False)
        if tuple(ir.shape) != ref.full_shape:
            raise ValueError(f"IR shape {ir.shape} differs from the reference's {ref.full_shape}")
        work_ir, work_depth, mask = self._prepare(ir, depth_m)
        mask &= ref.mask
        cur_u8 = stretch_ir(work_ir, mask)
        initial = self._last_flow if self.params.warm_start else None
        flow = self._flow(ref.u8, cur_u8, initial)
        if self.params.warm_start:
            self._last_flow = flow
        result = self._summarize(flow, mask, work_depth)
        if keep_fields:
            result.flow, result.mask = flow, mask
        return result

    def _summarize(
        self, flow: np.ndarray, mask: np.ndarray, work_depth: np.ndarray | None
    ) -> ShearResult:
        assert self._ref is not None
        indices = np.flatnonzero(mask)
        fraction = indices.size / mask.size if mask.size else 0.0
        if fraction < self.params.min_valid_fraction:
            result = ShearResult.empty(has_reference=True)
            result.valid_fraction = fraction
            return result
        vectors = flow.reshape(-1, 2)[indices]
        finite = np.isfinite(vectors).all()
        if not finite:  # neither method yields NaN from finite images; stay safe anyway
            keep = np.isfinite(vectors).all(axis=1)
            vectors, indices = vectors[keep], indices[keep]
        to_full = 1.0 / self.params.scale
        mean, total, magnitude, direction, defined = _summarize_vectors(
            vectors, self.params.min_magnitude_px / to_full
        )
        result = ShearResult(
            has_reference=True,
            shear_px=mean * to_full,
            sum_px=total * to_full,
            magnitude_px=magnitude * to_full,
            direction=direction,
            direction_defined=defined,
            shear_mm=np.zeros(2),
            mm_defined=False,
            torsion_rad=0.0,
            valid_fraction=fraction,
        )
        geometry = self._ref.geometry
        if geometry is not None and work_depth is not None:
            s1, s2, d1, d2 = geometry.tangential_displacement_mm(flow, indices, work_depth)
            if s1.shape[0] >= 3:
                result.shear_mm = np.array([d1.mean(), d2.mean()])
                result.torsion_rad, _ = rotation_about_centroid(s1, s2, d1, d2)
                result.mm_defined = True
        if not result.mm_defined:
            width = mask.shape[1]
            rows, cols = np.divmod(indices, width)
            result.torsion_rad, _ = rotation_about_centroid(
                cols.astype(np.float64),
                rows.astype(np.float64),
                vectors[:, 0].astype(np.float64),
                vectors[:, 1].astype(np.float64),
            )
        return result


def draw_overlay(
    ir: np.ndarray,
    result: ShearResult,
    *,
    step_px: int = 12,
    arrow_gain: float = 10.0,
    flow_gain: float = 2.0,
) -> np.ndarray:
    """IR with the flow field and the summed arrow, as in the paper's handover figure.

    Args:
        ir: full-resolution IR image.
        result: an estimate from :meth:`ShearTracker.update` with ``keep_fields=True``
            (without fields only the summed arrow is drawn).
        step_px: grid spacing of the small flow arrows (full-resolution pixels).
        arrow_gain: length of the summed arrow per pixel of mean shear.
        flow_gain: the small arrows are the flow scaled by this (sub-pixel flow is
            invisible at scale 1).

    Returns:
        uint8 BGR ``(h, w, 3)`` image.
    """
    valid = (ir > 0) & (ir < 65535)
    bgr = cv2.cvtColor(stretch_ir(ir, valid), cv2.COLOR_GRAY2BGR)
    h, w = ir.shape
    if result.flow is not None and result.mask is not None:
        fh, fw = result.flow.shape[:2]
        sx, sy = w / fw, h / fh
        for y in range(step_px // 2, h, step_px):
            for x in range(step_px // 2, w, step_px):
                fy_i, fx_i = min(int(y / sy), fh - 1), min(int(x / sx), fw - 1)
                if not result.mask[fy_i, fx_i]:
                    continue
                dx, dy = result.flow[fy_i, fx_i]
                if not (math.isfinite(dx) and math.isfinite(dy)):
                    continue
                end = (int(round(x + dx * sx * flow_gain)), int(round(y + dy * sy * flow_gain)))
                cv2.arrowedLine(bgr, (x, y), end, (0, 255, 0), 1, tipLength=0.3)
    centre = (w // 2, h // 2)
    if result.has_reference:
        vector = result.shear_px * arrow_gain
        end = (int(round(centre[0] + vector[0])), int(round(centre[1] + vector[1])))
        color = (0, 0, 255) if result.direction_defined else (128, 128, 128)
        cv2.arrowedLine(bgr, centre, end, color, 2, tipLength=0.25)
        cv2.circle(bgr, centre, 3, color, -1)
    return bgr
