"""The shear of one bubble against a reference frame, and when to take that reference.

:class:`ShearTracker` holds one reference (stretched IR, mask, membrane geometry) and
turns each later frame into a frozen :class:`ShearResult`. :class:`GraspShear` is the
shear tracker node's logic without sockets: one tracker per bubble, and the timing of
the references (taken at the first frame stamped at or after a stable grasp, dropped on
release, retaken on a reset or when the camera changes mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.camera import PinholeCamera
from geometry.planar import rotation_about_centroid
from perception.shear.flow import (
    DenseFlow,
    membrane_mask,
    resize_for_flow,
    scaled_camera,
    stretch_ir,
    summarize_vectors,
)
from perception.shear.membrane import MembraneGeometry
from perception.shear.params import ShearParams


@dataclass(frozen=True)
class ShearResult:
    """One shear estimate, built once and never changed; arrays are float64 unless said
    otherwise.

    Attributes:
        has_reference: False when no reference was set (everything else is zero).
        shear_px: mean displacement over the mask, full-resolution pixels ``(dx, dy)``.
        sum_px: the paper's sum of the flow over the mask (working-resolution pixels
            count, full-resolution displacement).
        magnitude_px: ``|shear_px|``.
        direction: ``shear_px / magnitude_px`` or ``(0, 0)`` when undefined.
        direction_defined: whether ``direction`` means anything.
        shear_m: mean tangential membrane displacement ``(t1, t2)`` in metres (zero
            without depth).
        metric_defined: whether ``shear_m`` and the metric torsion were computed.
        torsion_rad: rotation about the contact normal (metric when ``metric_defined``, else
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
    shear_m: np.ndarray
    metric_defined: bool
    torsion_rad: float
    valid_fraction: float
    flow: np.ndarray | None = None
    mask: np.ndarray | None = None

    @classmethod
    def empty(cls, *, has_reference: bool, valid_fraction: float = 0.0) -> ShearResult:
        """A finite 'nothing measured' result."""
        return cls(
            has_reference=has_reference,
            shear_px=np.zeros(2),
            sum_px=np.zeros(2),
            magnitude_px=0.0,
            direction=np.zeros(2),
            direction_defined=False,
            shear_m=np.zeros(2),
            metric_defined=False,
            torsion_rad=0.0,
            valid_fraction=valid_fraction,
        )


@dataclass(frozen=True)
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
    def reference_geometry(self) -> MembraneGeometry | None:
        """The reference membrane's geometry (None without a reference or its depth)."""
        return None if self._ref is None else self._ref.geometry

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
            depth_m: optional ``(h, w)`` z-depth (NaN invalid), for the mask and ``shear_m``.
            camera: the full-resolution camera; with ``depth_m``, enables ``shear_m``.
            basis: optional tangent frame for ``shear_m`` and the torsion (rows
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
                ``shear_m`` when the reference had depth and a camera.
            keep_fields: also return the flow and mask (for overlays).

        Returns:
            A finite :class:`ShearResult`; ``has_reference=False`` without a reference.
        """
        if self._ref is None:
            return ShearResult.empty(has_reference=False)
        flow, mask, work_depth = self.track(ir, depth_m)
        return self._summarize(flow, mask, work_depth, keep_fields)

    def track(
        self, ir: np.ndarray, depth_m: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The dots' flow of this frame against the reference, without the summary
        :meth:`update` makes of it (for a caller that reads the field itself).

        Returns:
            ``(flow, mask, work_depth)`` at the working resolution: the flow
            ``(h, w, 2)`` in working pixels, the membrane's mask (this frame's and the
            reference's), the depth resized (None without ``depth_m``).

        Raises:
            ValueError: without a reference, or for an image of another shape.
        """
        ref = self._ref
        if ref is None:
            raise ValueError("no reference: call set_reference first")
        if tuple(ir.shape) != ref.full_shape:
            raise ValueError(f"IR shape {ir.shape} differs from the reference's {ref.full_shape}")
        work_ir, work_depth, mask = self._prepare(ir, depth_m)
        mask &= ref.mask
        cur_u8 = stretch_ir(work_ir, mask)
        initial = self._last_flow if self.params.warm_start else None
        flow = self._flow(ref.u8, cur_u8, initial)
        if self.params.warm_start:
            self._last_flow = flow
        return flow, mask, work_depth

    def _summarize(
        self,
        flow: np.ndarray,
        mask: np.ndarray,
        work_depth: np.ndarray | None,
        keep_fields: bool,
    ) -> ShearResult:
        assert self._ref is not None
        indices = np.flatnonzero(mask)
        fraction = indices.size / mask.size if mask.size else 0.0
        if fraction < self.params.min_valid_fraction:
            return ShearResult.empty(has_reference=True, valid_fraction=fraction)
        vectors = flow.reshape(-1, 2)[indices]
        if not np.isfinite(vectors).all():
            # Neither method yields NaN from finite images; stay safe anyway.
            keep = np.isfinite(vectors).all(axis=1)
            vectors, indices = vectors[keep], indices[keep]
        to_full = 1.0 / self.params.scale
        mean, total, magnitude, direction, defined = summarize_vectors(
            vectors, self.params.min_magnitude_px / to_full
        )
        shear_m = np.zeros(2)
        torsion_rad: float | None = None
        geometry = self._ref.geometry
        if geometry is not None and work_depth is not None:
            s1, s2, d1, d2 = geometry.tangential_displacement_m(flow, indices, work_depth)
            if s1.shape[0] >= 3:
                shear_m = np.array([d1.mean(), d2.mean()])
                torsion_rad, _ = rotation_about_centroid(s1, s2, d1, d2)
        metric = torsion_rad is not None
        if torsion_rad is None:
            rows, cols = np.divmod(indices, mask.shape[1])
            torsion_rad, _ = rotation_about_centroid(
                cols.astype(np.float64),
                rows.astype(np.float64),
                vectors[:, 0].astype(np.float64),
                vectors[:, 1].astype(np.float64),
            )
        return ShearResult(
            has_reference=True,
            shear_px=mean * to_full,
            sum_px=total * to_full,
            magnitude_px=magnitude * to_full,
            direction=direction,
            direction_defined=defined,
            shear_m=shear_m,
            metric_defined=metric,
            torsion_rad=torsion_rad,
            valid_fraction=fraction,
            flow=flow if keep_fields else None,
            mask=mask if keep_fields else None,
        )


class GraspShear:
    """Both bubbles' shear against their stable-grasp references (the node's logic).

    The reference of each bubble is the first frame stamped at or after the moment the
    grasp became stable; it is dropped when the grasp is released, and retaken on
    :meth:`reset` (while the grasp is stable) or when a frame's shape differs from the
    reference's (the camera changed mode mid-grasp).
    """

    def __init__(self, params: ShearParams, sensors: tuple[str, ...] = ("left", "right")) -> None:
        self.sensors = sensors
        self.trackers = {sensor: ShearTracker(params) for sensor in sensors}
        self.stable = False
        self.stable_since_nanos = 0
        self.want_reference = dict.fromkeys(sensors, False)

    def grasp(self, *, stable: bool, event: str, stamp_nanos: int) -> None:
        """A grasp state: a new stable grasp asks for new references; a release drops them."""
        became_stable = stable and (not self.stable or event == "stable")
        if became_stable:
            self.stable_since_nanos = stamp_nanos
            self._drop(self.sensors, want=True)
        elif not stable and (self.stable or event == "released"):
            self._drop(self.sensors, want=False)
        self.stable = stable

    def reset(self, sensor: str, stamp_nanos: int) -> None:
        """Retake ``sensor``'s reference (``""``: every bubble's) from ``stamp_nanos`` on.

        Raises:
            ValueError: for a sensor this tracker does not know.
        """
        if sensor not in ("", *self.sensors):
            raise ValueError(f"unknown sensor {sensor!r}; expected one of {self.sensors} or ''")
        self._drop(self.sensors if sensor == "" else (sensor,), want=self.stable)
        self.stable_since_nanos = min(self.stable_since_nanos, stamp_nanos)

    def _drop(self, sensors: tuple[str, ...], *, want: bool) -> None:
        for sensor in sensors:
            self.trackers[sensor].drop_reference()
            self.want_reference[sensor] = want

    def image(
        self,
        sensor: str,
        ir: np.ndarray,
        depth_m: np.ndarray | None,
        camera: PinholeCamera,
        *,
        stamp_nanos: int,
        basis: np.ndarray | None = None,
        keep_fields: bool = False,
    ) -> tuple[ShearResult, bool]:
        """The shear of one frame; takes it as the reference when one is due.

        Args:
            sensor: which bubble.
            ir, depth_m, camera: the frame (see :meth:`ShearTracker.set_reference`).
            stamp_nanos: the frame's stamp.
            basis: the tangent frame for a new reference (None: fit the membrane).
            keep_fields: also return the flow and mask.

        Returns:
            ``(result, retaken)``; ``retaken`` is True when the frame's shape differed from
            the reference's, so the old reference was dropped.
        """
        tracker = self.trackers[sensor]
        shape = tracker.reference_shape
        retaken = shape is not None and shape != ir.shape
        if retaken:
            self._drop((sensor,), want=self.stable)
        if self.want_reference[sensor] and stamp_nanos >= self.stable_since_nanos:
            tracker.set_reference(ir, depth_m, camera, basis)
            self.want_reference[sensor] = False
        return tracker.update(ir, depth_m, keep_fields=keep_fields), retaken
