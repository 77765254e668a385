"""What one bubble's sensors say about its contact: the inputs of every force estimator.

Per frame of one bubble, from its depth and IR images and its pressure:

* the **patch**: pixels pressed in against the free bubble's depth (the contact filter of
  ``perception.contact``), its **area projected on the plate** (each pixel's footprint
  ``r^2 dOmega / |d . m|``, ``m`` the plate's normal, ``d`` the pixel's ray) and its
  **displaced volume** (the footprint times how far the membrane moved in), its
  centroid in the tool frame, and the **pressure's rise** over the free bubble's (the
  gas law makes it a measure of the whole displaced volume, seen or not);
* the **dots' tangential displacement** in metres along the tool's y and z: dense
  flow of the IR dot pattern against the *tare* frame (the jaws just closed on the
  object, before it loads them tangentially: the bubble's zero, as a force-torque
  sensor is tared), warm-started frame to frame, each dot back-projected before and
  after (``perception.shear.ShearTracker`` does the flow and the geometry). The mean
  over the patch and over its edge (pixels within ``edge_px`` of the patch's border),
  the median over its core (the rest: the object's slide in the hand while the patch
  sticks, robust to the part of the patch the flow misreads), and the rotation of the
  patch's dots about the plate's normal.
  (Against the free bubble instead, the flow must follow the whole indentation, and
  its error, a millimetre and more of apparent shift that depends on the object,
  swamps the shear.)

Frames: tool (``docs/design.md``). The plate's inward normal is tool -x on the left
bubble (its plate sits at +x) and +x on the right one, so it follows from the camera's
pose that each frame carries.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Annotated

import cv2
import msgspec
import numpy as np
from msgspec import Meta

from geometry.camera import PinholeCamera
from geometry.planar import rotation_about_centroid
from perception.contact import ContactParams, ContactPatcher, contact_mask
from perception.force.slide import departing_share
from perception.shear import ShearParams, ShearTracker, resize_for_flow, tool_basis


class FeatureParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Knobs of the feature extraction."""

    contact: Annotated[
        ContactParams,
        Meta(
            description=(
                "the contact filter against the free bubble (a lower threshold than the"
                " pose's patch: a force needs the whole pressed area, rim included)."
            )
        ),
    ] = msgspec.field(
        default_factory=lambda: ContactParams(threshold_m=0.0015, min_component_px=40)
    )
    flow: Annotated[
        ShearParams,
        Meta(
            description=(
                "the dot flow (Farneback at half resolution, warm-started). DIS's ``fast``"
                " preset at half resolution is faster but estimates its finest flow at an"
                " eighth of the image: on ``world.sim``'s grasps it missed the object's"
                " slide on the latex by 0.26 mm at the median (Farneback: 0.018 mm;"
                " ``bench.force``, ``shift_err_mm_median``), and read a third of it on the"
                " square bottle's flat face, where no shift limit could see the slide coming."
            )
        ),
    ] = msgspec.field(default_factory=lambda: ShearParams(scale=0.5, warm_start=True))
    edge_px: Annotated[
        int,
        Meta(
            ge=1,
            description=(
                "working-resolution pixels from the patch's border that count as its edge."
            ),
        ),
    ] = 3
    slide_frames: Annotated[
        int,
        Meta(
            ge=1,
            description=(
                "frames over which each dot's velocity is taken for the share of the patch"
                " leaving its rigid motion (``departing_share``; the dots' flow is noisy"
                " from one frame to the next)."
            ),
        ),
    ] = 4
    slide_cell_m: Annotated[
        float,
        Meta(gt=0, description="the cells (m) over which those velocities are averaged."),
    ] = 0.003
    slide_m_per_s: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "a cell departs from the patch's rigid motion when its speed off it passes"
                " this (1.5 mm/s: 0.05 mm a frame at 30 Hz, half the speed from which"
                " world.mujoco's truth counts a point sliding; the flow blurs a sliding"
                " point with its stuck neighbours)."
            ),
        ),
    ] = 0.0015
    min_patch_px: Annotated[
        int,
        Meta(
            ge=3,
            description=(
                "fewer working pixels of tracked patch than this: no tangential "
                "measurement (the patch is too small to measure)."
            ),
        ),
    ] = 12


@dataclass(frozen=True)
class ContactFeatures:
    """One bubble's contact at one frame (see the module docstring); SI units, tool frame.

    ``tracked`` is False while the dots cannot be followed (no free reference yet, or a
    patch under ``min_patch_px``): the shifts are then zero. ``departing_share`` is the
    share of the patch's dots whose motion over the last frames left the patch's rigid
    motion (``perception.force.slide``; 0 without stamps or history).
    """

    in_contact: bool
    tracked: bool
    pressure_pa: float
    pressure_rise_pa: float  # over the free bubble's
    area_m2: float
    volume_m3: float
    centroid_in_tool: np.ndarray  # (3,)
    normal_in_tool: np.ndarray  # (3,), the plate's inward normal
    shift_m: np.ndarray  # (2,) mean over the patch, tool (y, z)
    core_shift_m: np.ndarray  # (2,)
    edge_shift_m: np.ndarray  # (2,)
    torsion_rad: float  # about tool +x
    patch_px: int
    departing_share: float = 0.0

    @classmethod
    def empty(cls, pressure_pa: float, normal_in_tool: np.ndarray) -> ContactFeatures:
        zero2 = np.zeros(2)
        return cls(
            False, False, pressure_pa, 0.0, 0.0, 0.0, np.zeros(3), normal_in_tool, zero2, zero2,
            zero2, 0.0, 0,
        )  # fmt: skip


def shift_per_pressure(f: ContactFeatures, min_pressure_pa: float = 100.0) -> float:
    """The core's tangential shift per pascal of gauge pressure (m/Pa; 0 untracked or
    under ``min_pressure_pa``): how near the patch is to slipping, since a point of the
    membrane slips past the shift ``friction p / k`` (``perception.force.slip``)."""
    if not f.tracked or f.pressure_pa < min_pressure_pa:
        return 0.0
    return float(np.hypot(*f.core_shift_m)) / f.pressure_pa


def inward_normal_in_tool(tool_from_sensor: np.ndarray) -> np.ndarray:
    """The plate's inward normal: towards the other finger (tool -x for the left plate)."""
    return np.array([-1.0 if tool_from_sensor[0, 3] > 0 else 1.0, 0.0, 0.0])


def rim_correction(indent_m: np.ndarray, threshold_m: float) -> float:
    """How much larger the patch is than its part pressed past the threshold.

    A cylinder pressed ``d`` into the membrane touches a band ``2 sqrt(2 R d)`` wide; the
    filter sees only where the indentation exceeds the threshold ``t``, a band
    ``2 sqrt(2 R (d - t))`` wide: the ratio is ``sqrt(d / (d - t))`` whatever ``R``.
    ``d`` is a robust maximum (the 95th percentile) of the patch's indentation.
    """
    finite = indent_m[np.isfinite(indent_m)]
    if finite.size == 0:
        return 1.0
    deepest = float(np.percentile(finite, 95))
    if deepest <= threshold_m * 1.25:
        return math.sqrt(5.0)
    return math.sqrt(deepest / (deepest - threshold_m))


def footprint_m2(
    depth_m: np.ndarray,
    camera: PinholeCamera,
    normal_in_sensor: np.ndarray,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's footprint projected on a plane normal to ``normal_in_sensor``, and
    its range (m); NaN where the depth is invalid. With ``mask``, of its pixels only
    (1D, in ``depth_m[mask]``'s order)."""
    rays, solid = camera.unit_rays(), camera.pixel_solid_angle_sr()
    if mask is not None:
        at = np.flatnonzero(mask)
        depth_m, rays, solid = (
            depth_m.reshape(-1)[at],
            rays.reshape(-1, 3)[at],
            solid.reshape(-1)[at],
        )
    rng = depth_m / rays[..., 2]
    cos = np.abs(rays @ normal_in_sensor)
    with np.errstate(invalid="ignore", divide="ignore"):
        area = rng * rng * solid / np.maximum(cos, 0.05)
    return area, rng


class BubbleFeatures:
    """One bubble's feature extractor: the free reference, the dots' tare, each frame.

    Typical use: :meth:`free_frame` while the gripper is open and still (nothing
    touching), :meth:`tare` on the frame the jaws close on the object (before it loads
    the bubbles tangentially), :meth:`update` for every frame, :meth:`untare` when the
    jaws open.
    """

    def __init__(self, params: FeatureParams | None = None) -> None:
        self.params = params or FeatureParams()
        self._patcher = ContactPatcher(self.params.contact)
        self._tracker = ShearTracker(self.params.flow)
        self._free_pressure_pa = 0.0
        self._free: np.ndarray | None = None  # the free reference's mean depth (cached)
        # The patch's dots of the last frames (stamp, reference pixels, positions,
        # displacements), for the share leaving the rigid motion.
        self._dots: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque(
            maxlen=self.params.slide_frames + 1
        )

    @property
    def has_reference(self) -> bool:
        """Whether the free bubble's reference exists."""
        return self._patcher.has_reference("bubble")

    @property
    def tared(self) -> bool:
        return self._tracker.has_reference

    def clear(self) -> None:
        """Forget the free reference (a new one is being taken)."""
        self._patcher.clear_reference("bubble")
        self._free = None

    def free_frame(self, depth_m: np.ndarray, pressure_pa: float) -> None:
        """Add a frame of the free bubble to its reference (depth averaged; the newest
        pressure is the free one)."""
        self._patcher.update_reference("bubble", depth_m)
        self._free = None  # the mean changed
        self._free_pressure_pa = pressure_pa

    def tare(
        self,
        ir: np.ndarray,
        depth_m: np.ndarray,
        camera: PinholeCamera,
        tool_from_sensor: np.ndarray,
    ) -> None:
        """Take this frame as the dots' zero tangential load (the jaws just closed)."""
        self._tracker.set_reference(ir, depth_m, camera, tool_basis(tool_from_sensor))
        self._dots.clear()

    def untare(self) -> None:
        """The jaws opened: no tangential reference until the next :meth:`tare`."""
        self._tracker.drop_reference()
        self._dots.clear()

    def update(
        self,
        ir: np.ndarray,
        depth_m: np.ndarray,
        pressure_pa: float,
        camera: PinholeCamera,
        tool_from_sensor: np.ndarray,
        stamp_secs: float | None = None,
    ) -> ContactFeatures:
        """The features of one frame (finite always; see :class:`ContactFeatures`);
        ``stamp_secs``, the frame's time, dates the dots' velocities (without it no
        ``departing_share``)."""
        normal = inward_normal_in_tool(tool_from_sensor)
        if self._free is None:
            self._free = self._patcher.reference("bubble")
        free = self._free
        if free is None or free.shape != depth_m.shape:
            return ContactFeatures.empty(pressure_pa, normal)
        mask = contact_mask(depth_m, free, self.params.contact)
        if not mask.any():
            return ContactFeatures.empty(pressure_pa, normal)
        rot = tool_from_sensor[:3, :3]
        rise = pressure_pa - self._free_pressure_pa
        # Per pixel of the patch only (the rest of the image does not enter).
        at = np.flatnonzero(mask)
        weights, rng = footprint_m2(depth_m, camera, rot.T @ normal, mask)
        indent = free.reshape(-1)[at] / camera.unit_rays()[..., 2].reshape(-1)[at] - rng
        area = float(np.nansum(weights)) * rim_correction(indent, self.params.contact.threshold_m)
        volume = float(np.nansum(weights * indent))
        depth = depth_m.reshape(-1)[at]
        points = np.where(depth > 0, depth, np.nan)[:, None] * camera.rays().reshape(-1, 3)[at]
        good = np.isfinite(points).all(axis=1) & np.isfinite(weights)
        centroid_s = (points[good] * weights[good, None]).sum(0) / max(weights[good].sum(), 1e-12)
        centroid = rot @ centroid_s + tool_from_sensor[:3, 3]
        shifts = self._shifts(ir, depth_m, mask, stamp_secs) if self.tared else None
        if shifts is None:
            self._dots.clear()
            zero2 = np.zeros(2)
            return ContactFeatures(
                True, False, pressure_pa, rise, area, volume, centroid, normal, zero2, zero2,
                zero2, 0.0, int(mask.sum()),
            )  # fmt: skip
        mean, core, edge, torsion, count, departing = shifts
        return ContactFeatures(
            True, True, pressure_pa, rise, area, volume, centroid, normal, mean, core, edge,
            torsion, count, departing,
        )  # fmt: skip

    def _shifts(
        self, ir: np.ndarray, depth_m: np.ndarray, mask: np.ndarray, stamp_secs: float | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int, float] | None:
        """Mean, core (median) and edge tangential shift of the patch's dots, their
        torsion, and the share of them leaving the patch's rigid motion."""
        geometry = self._tracker.reference_geometry
        if geometry is None:
            return None
        flow, membrane, work_depth = self._tracker.track(ir, depth_m)
        if work_depth is None:
            return None
        scale = self.params.flow.scale
        work_patch = resize_for_flow(mask.astype(np.float32), scale) >= 0.5
        work_patch &= membrane
        if work_patch.sum() < self.params.min_patch_px:
            return None
        # The patch's edge: within edge_px of its border (distance inside the patch).
        dist = cv2.distanceTransform(work_patch.astype(np.uint8), cv2.DIST_L2, 3)
        indices = np.flatnonzero(work_patch)
        s1, s2, d1, d2, kept = geometry.tangential_displacement_full(flow, indices, work_depth)
        if s1.size < self.params.min_patch_px:
            return None
        edge = dist.reshape(-1)[kept] <= self.params.edge_px
        disp = np.stack([d1, d2], axis=1)
        mean = disp.mean(axis=0)
        # The core's median, not its mean: while the patch sticks its dots move as one
        # with the object, but the end of the patch the object slides towards reads a
        # fraction of the slide, and its dots (a sixth of the core) dragged the mean
        # 8-19% short (docs/force.md, "What the bubble measures").
        core = np.median(disp[~edge], axis=0) if (~edge).sum() >= 3 else mean
        rim = disp[edge].mean(axis=0) if edge.sum() >= 3 else mean
        torsion, _ = rotation_about_centroid(s1, s2, d1, d2)
        departing = self._departing(stamp_secs, kept, np.stack([s1, s2], axis=1), disp)
        return mean, core, rim, float(torsion), int(s1.size), departing

    def _departing(
        self, stamp_secs: float | None, pixels: np.ndarray, at: np.ndarray, disp: np.ndarray
    ) -> float:
        """The share of the patch's dots whose velocity over the window left the rigid
        motion (``perception.force.slide``): the dots are the reference's pixels, the
        same material points frame after frame."""
        if stamp_secs is None:
            return 0.0
        self._dots.append((stamp_secs, pixels, at, disp))
        if len(self._dots) <= self.params.slide_frames:
            return 0.0
        t0, pixels0, _, disp0 = self._dots[0]
        if stamp_secs <= t0:
            return 0.0
        # The dots of both frames: the reference's pixels, ascending in each.
        found = np.searchsorted(pixels0, pixels)
        found[found == len(pixels0)] = 0
        hit = pixels0[found] == pixels
        now, then = np.flatnonzero(hit), found[hit]
        p = self.params
        return departing_share(
            at[now],
            (disp[now] - disp0[then]) / (stamp_secs - t0),
            cell_m=p.slide_cell_m,
            speed_m_per_s=p.slide_m_per_s,
        )
