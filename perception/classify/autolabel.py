"""The random grasp generator of the auto-labelling pipeline (paper, tactile classification).

The paper's robot picks objects with its antipodal grasp generator, drops them at
random and picks them again, so the training set covers the grasps the robot will make.
Here each grasp ``i`` of a run is drawn from a generator seeded with ``(seed, i)``, so a
run is deterministic per seed and a resumed run draws the same grasps it would have:

* the object: classes come in shuffled blocks of one of each, so counts stay balanced;
  with ``variants`` (``train`` or ``held_out``) each grasp's object is a variant of its
  class drawn from that split of ``geometry.variants`` (its own stream: the rest of the
  draw is what it would be without), the class's reference shape otherwise;
* the pose after a random drop: any turn about the object's own axis, the axis tilted
  towards the approach direction (grasps from above and from the side) and a little
  towards the closing direction, a small shift across and along the fingers;
* the grasp height: anywhere along the object's axis but a margin at the ends (the
  rim, handle, neck, stem and foot are all fair); a training run may ask for more
  grasps near the ends (``end_fraction``), where objects look most alike
  (docs/classifier.md): a held-out set keeps the generator's own spread;
* feasibility, as a grasp generator would check it: what lies between the bubbles (the
  object's surface inside the bubbles' footprint) must fit the gripper (WSG 50 stroke,
  docs/facts.md, less the bubbles), and nothing may hit a plate; the object is centred
  between the jaws. Infeasible draws are redrawn.

The result is what the supervisor sends: the object, ``tool_from_object`` (4x4), and
the grasp command (width to close to, force).
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from geometry import objects, variants
from geometry.gripper import DEFAULT_GRIPPER, GripperGeometry
from geometry.se3 import rotation_about

DEFAULT_OBJECTS = ("mug", "pet_bottle", "square_bottle", "wine_glass")
VARIANT_CHOICES = ("none", *variants.SPLITS)
_X, _Y, _Z = np.eye(3)


class GraspGeneratorParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Ranges of the random grasps (uniform draws within +- each value)."""

    objects: Annotated[
        tuple[str, ...], Meta(description="object names (``geometry.objects``) to grasp.")
    ] = DEFAULT_OBJECTS
    variants: Annotated[
        str,
        Meta(
            description=(
                "``none`` (each class's reference shape), or ``train`` / ``held_out``: a "
                "variant of the class from that split of ``geometry.variants.SPLITS``."
            )
        ),
    ] = "none"
    seed: Annotated[
        int, Meta(description="the run's seed; grasp ``i`` depends only on ``(seed, i)``.")
    ] = 0
    approach_tilt_deg: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "tilt of the object axis from across the fingers towards the approach "
                "direction (90 would be a grasp straight down the axis)."
            ),
        ),
    ] = 40.0
    skew_deg: Annotated[
        float, Meta(ge=0, description="tilt of the object axis towards the closing direction.")
    ] = 8.0
    offset_m: Annotated[
        float,
        Meta(
            ge=0, description="shift of the grasp point across the fingers and along the approach."
        ),
    ] = 0.006
    height_margin_m: Annotated[
        float, Meta(ge=0, description="grasp heights stay this far from the object's ends.")
    ] = 0.006
    end_fraction: Annotated[
        float,
        Meta(
            ge=0,
            le=1,
            description=(
                "share of the draws whose height lies within ``end_band_m`` of an end "
                "(either, at random) instead of anywhere. 0 (the default) draws exactly"
                " what a run without it draws."
            ),
        ),
    ] = 0.0
    end_band_m: Annotated[
        float, Meta(description="width of that band, from the object's end (margin included).")
    ] = 0.02
    squeeze_min_m: Annotated[
        float, Meta(description="how much the jaws close past first contact.")
    ] = 0.006
    squeeze_max_m: Annotated[
        float, Meta(description="how much the jaws close past first contact.")
    ] = 0.014
    force_min_n: Annotated[float, Meta(description="grasp force limit.")] = 8.0
    force_max_n: Annotated[float, Meta(description="grasp force limit.")] = 25.0
    clearance_m: Annotated[
        float, Meta(description="what the gripper must have to spare at full opening.")
    ] = 0.004
    max_tries: Annotated[
        int,
        Meta(ge=1, description="draws before giving up on a grasp (an object that never fits)."),
    ] = 500

    def __post_init__(self) -> None:
        if not self.objects:
            raise ValueError("`objects` must name at least one object, got ()")
        for name in self.objects:
            if name not in objects.NAMES:
                raise ValueError(f"`objects`: unknown object {name!r}; valid: {objects.NAMES}")
        if self.variants not in VARIANT_CHOICES:
            raise ValueError(f"`variants` must be one of {VARIANT_CHOICES}, got {self.variants!r}")
        if self.variants != "none":
            missing = [n for n in self.objects if n not in variants.FAMILIES]
            if missing:
                raise ValueError(f"`variants`: no variant family for {missing}")
        if not self.end_band_m > self.height_margin_m:
            raise ValueError(
                f"`end_band_m` must be > height_margin_m ({self.height_margin_m!r}), "
                f"got {self.end_band_m!r}"
            )
        if not 0 <= self.squeeze_min_m <= self.squeeze_max_m:
            raise ValueError(
                f"`squeeze_max_m` must be >= squeeze_min_m >= 0, got {self.squeeze_max_m!r}"
            )
        if not 0 < self.force_min_n <= self.force_max_n:
            raise ValueError(f"`force_max_n` must be >= force_min_n > 0, got {self.force_max_n!r}")


@dataclass(frozen=True)
class GraspSample:
    """One random grasp: which object, where it sits in the hand, how to close on it."""

    grasp_id: int
    object_name: str
    class_label: str
    tool_from_object: np.ndarray  # 4x4, the object where the gripper will close on it
    height_m: float  # grasp point along the object's axis, from its centre
    yaw_deg: float
    approach_tilt_deg: float
    skew_deg: float
    extent_m: float  # object width between the bubbles
    contact_width_m: float  # jaw opening at first contact
    grasp_width_m: float  # jaw opening commanded (contact less the squeeze)
    force_n: float
    tries: int
    variant: int | None = None  # the class's variant (geometry.variants), None: reference

    def to_params(self) -> dict[str, Any]:
        """JSON-able record for the dataset manifest and the supervisor's events (a
        reference shape's record has no ``variant``)."""
        out = asdict(self)
        if self.variant is None:
            del out["variant"]
        out["tool_from_object"] = np.round(self.tool_from_object, 6).tolist()
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in out.items()}


@functools.lru_cache(maxsize=256)
def _model(name: str, variant: int | None) -> objects.ObjectModel:
    return objects.make(name) if variant is None else variants.make_variant(name, variant)


@functools.lru_cache(maxsize=256)
def _axis_span_m(name: str, variant: int | None) -> tuple[float, float]:
    lo, hi = _model(name, variant).bounds_m()
    return float(lo[2]), float(hi[2])


def end_distance_m(object_name: str, height_m: float, variant: int | None = None) -> float:
    """How far a grasp height (``GraspSample.height_m``) lies from the object's nearer end
    (of the grasp's variant, if it had one)."""
    lo, hi = _axis_span_m(object_name, variant)
    return min(height_m - lo, hi - height_m)


@functools.lru_cache(maxsize=256)
def _surface(name: str, variant: int | None) -> np.ndarray:
    # A fixed sample of the surface: extents must not depend on the grasp's draw.
    return _model(name, variant).sample_surface(4000, np.random.default_rng(12345))


class GraspGenerator:
    """Draws feasible random grasps (see the module docstring)."""

    def __init__(
        self, params: GraspGeneratorParams, gripper: GripperGeometry = DEFAULT_GRIPPER
    ) -> None:
        self.params = params
        self.gripper = gripper
        bubble = gripper.bubble
        self.footprint = bubble.footprint_semi_axes_m()  # (across, along) the finger
        # Jaw opening at first contact is the object's extent plus this (the two caps
        # protrude cap_height_m from plates set plate_outset_m outboard of the jaws).
        self.contact_extra_m = 2 * (bubble.cap_height_m - gripper.plate_outset_m)
        self.max_extent_m = gripper.max_width_m - self.contact_extra_m - params.clearance_m

    def object_for(self, grasp_id: int) -> str:
        """The object of grasp ``grasp_id``: one of each per shuffled block."""
        names = self.params.objects
        block, index = divmod(grasp_id, len(names))
        order = np.random.default_rng([self.params.seed, block, 1]).permutation(len(names))
        return names[int(order[index])]

    def variant_for(self, grasp_id: int) -> int | None:
        """The variant of grasp ``grasp_id``'s object (None without ``variants``)."""
        if self.params.variants == "none":
            return None
        ids = variants.SPLITS[self.params.variants]
        rng = np.random.default_rng([self.params.seed, grasp_id, 4])
        return int(ids[int(rng.integers(len(ids)))])

    def sample(self, grasp_id: int) -> GraspSample:
        """Grasp ``grasp_id`` of this seed (the same every time it is asked).

        Raises:
            ValueError: ``grasp_id`` < 0, or no feasible grasp in ``max_tries`` draws.
        """
        if grasp_id < 0:
            raise ValueError(f"grasp_id must be >= 0, got {grasp_id}")
        p = self.params
        name = self.object_for(grasp_id)
        variant = self.variant_for(grasp_id)
        model = _model(name, variant)
        lo, hi = model.bounds_m()
        surface = _surface(name, variant)
        rng = np.random.default_rng([p.seed, grasp_id, 2])
        # Its own stream, so that end_fraction = 0 leaves every other draw as it was.
        end_rng = np.random.default_rng([p.seed, grasp_id, 3])
        for tries in range(1, p.max_tries + 1):
            yaw = rng.uniform(-180.0, 180.0)
            tilt = rng.uniform(-p.approach_tilt_deg, p.approach_tilt_deg)
            skew = rng.uniform(-p.skew_deg, p.skew_deg)
            low, high = lo[2] + p.height_margin_m, hi[2] - p.height_margin_m
            if p.end_fraction > 0 and end_rng.uniform() < p.end_fraction:
                if end_rng.uniform() < 0.5:
                    high = lo[2] + p.end_band_m
                else:
                    low = hi[2] - p.end_band_m
            height = rng.uniform(low, high)
            offset = rng.uniform(-p.offset_m, p.offset_m, size=2)
            squeeze = rng.uniform(p.squeeze_min_m, p.squeeze_max_m)
            force = rng.uniform(p.force_min_n, p.force_max_n)
            # Object axis across the fingers (tool y), then tilted; yaw about its own axis.
            rot = (
                rotation_about(_Z, math.radians(skew))
                @ rotation_about(_X, math.radians(tilt))
                @ rotation_about(_X, -math.pi / 2)
                @ rotation_about(_Z, math.radians(yaw))
            )
            points = surface @ rot.T - rot @ np.array([0.0, 0.0, height])
            grasp = self._fit(points, offset, squeeze)
            if grasp is None:
                continue
            shift_x, extent, contact_width, grasp_width = grasp
            pose = np.eye(4)
            pose[:3, :3] = rot
            pose[:3, 3] = -rot @ np.array([0.0, 0.0, height]) + np.array([shift_x, *offset])
            return GraspSample(
                grasp_id=grasp_id,
                object_name=name,
                class_label=model.class_label,
                tool_from_object=pose,
                height_m=float(height),
                yaw_deg=float(yaw),
                approach_tilt_deg=float(tilt),
                skew_deg=float(skew),
                extent_m=extent,
                contact_width_m=contact_width,
                grasp_width_m=grasp_width,
                force_n=float(force),
                tries=tries,
                variant=variant,
            )
        what = name if variant is None else f"{name} variant {variant}"
        raise ValueError(f"grasp {grasp_id}: no feasible grasp of {what!r} in {p.max_tries} tries")

    def _fit(
        self, points: np.ndarray, offset: np.ndarray, squeeze: float
    ) -> tuple[float, float, float, float] | None:
        """Centre the object between the jaws; None if it does not fit or hits a plate.

        Returns ``(shift_x, extent, contact_width, grasp_width)``: the shift along the
        closing direction that makes both bubbles touch at once, the object's width as
        the bubbles see it, the opening at first contact and the commanded opening.
        """
        points = points + np.array([0.0, *offset])
        bubble = self.gripper.bubble
        outset = self.gripper.plate_outset_m
        # Rest membrane height above the plate where each point faces it (NaN off the cap).
        cap = bubble.height_m(points[:, 1], points[:, 2])
        on_cap = np.isfinite(cap)
        if np.count_nonzero(on_cap) < 20:  # nothing (or a sliver) between the bubbles
            return None
        x, h = points[on_cap, 0], cap[on_cap]
        # The left bubble (plate at +x) first touches the object at the largest opening
        # w with w / 2 + outset - h <= x, i.e. w = 2 (x + h - outset); the right mirrors.
        width_left = float(np.max(2 * (x + h - outset)))
        width_right = float(np.max(2 * (-x + h - outset)))
        shift = (width_right - width_left) / 4
        contact_width = (width_left + width_right) / 2
        if contact_width > self.gripper.max_width_m - self.params.clearance_m:
            return None
        if contact_width <= squeeze:  # would need a negative opening
            return None
        grasp_width = contact_width - squeeze
        # Plates are a little larger than the cap's footprint; nothing there may pass one.
        across, along = self.footprint
        plate = (points[:, 1] / across) ** 2 + (points[:, 2] / along) ** 2 <= 1.3**2
        if np.any(np.abs(points[plate, 0] + shift) >= self.gripper.plate_x_m(grasp_width)):
            return None
        extent = contact_width - self.contact_extra_m
        return float(shift), float(extent), float(contact_width), float(grasp_width)
