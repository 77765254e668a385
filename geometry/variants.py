"""Families of object variants: each class a seeded spread of real dishware sizes.

A class (``mug``, ``pet_bottle``, ``square_bottle``, ``wine_glass``) is not one shape but a
family: variant ``v`` of a class is a set of dimensions drawn uniformly within the
family's ranges (docs/objects.md lists them with their sources) by a generator seeded
with the class and ``v`` only, so a variant is the same shape wherever it is built.
Variant ids are split once and for all: :data:`SPLITS` ``train`` ids (0-999) are the ones
a training set may use, ``held_out`` ids (1000-1999) the ones only a test may use.

    dims = variant_dims("mug", 1003)        # {"radius_m": ..., "handle_offset_m": ...}
    model = make_variant("mug", 1003)       # a geometry.objects.ObjectModel
    split_of(1003)                          # "held_out"
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geometry import objects

SPLITS: dict[str, range] = {"train": range(0, 1000), "held_out": range(1000, 2000)}
# A constant of the families: changing it changes every variant (and every dataset).
_FAMILY_SEED = 29


@dataclass(frozen=True)
class Family:
    """How a class's variants are drawn.

    Attributes:
        ranges: the drawn quantities and their uniform ranges ``(low, high)``: object
            dimensions in metres, or ``*_frac`` shape fractions that ``derive`` turns into
            dimensions.
        derive: the object's dimensions (``geometry.objects.make`` keywords) from a draw.
    """

    ranges: dict[str, tuple[float, float]]
    derive: Callable[[dict[str, float]], dict[str, float]]


def _dims_only(d: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in d.items() if k.endswith("_m")}


def _mug(d: dict[str, float]) -> dict[str, float]:
    out = _dims_only(d)
    h, rad = d["height_m"], d["handle_radius_m"]
    out["handle_span_m"] = d["handle_span_frac"] * h
    # The handle's centre moves up or down as far as leaves its ends on the body.
    room = h / 2 - out["handle_span_m"] / 2 - rad
    out["handle_offset_m"] = d["handle_offset_frac"] * room
    return out


FAMILIES: dict[str, Family] = {
    "mug": Family(
        {
            "radius_m": (0.040, 0.0475),  # 80-95 mm across
            "height_m": (0.095, 0.110),
            "handle_radius_m": (0.004, 0.007),  # the handle's bar, 8-14 mm thick
            "handle_reach_m": (0.025, 0.035),  # how far it stands off the body
            "handle_span_frac": (0.45, 0.70),  # its grip's length, of the height
            "handle_offset_frac": (-1.0, 1.0),  # where it sits, of the room up or down
        },
        _mug,
    ),
    "pet_bottle": Family(
        {
            "radius_m": (0.031, 0.035),  # 62-70 mm across
            "body_height_m": (0.125, 0.165),
            "shoulder_height_m": (0.030, 0.050),
            "neck_radius_m": (0.0125, 0.0150),  # 25-30 mm: 28 mm finishes and their caps
            "neck_height_m": (0.015, 0.025),
        },
        _dims_only,
    ),
    "square_bottle": Family(
        {
            "width_m": (0.055, 0.068),
            "body_height_m": (0.140, 0.185),
            "neck_radius_m": (0.0125, 0.0190),  # 28 to 38 mm finishes
            "neck_height_m": (0.020, 0.035),
        },
        _dims_only,
    ),
    "wine_glass": Family(
        {
            "foot_radius_m": (0.030, 0.040),  # ISO 3591: 65 +- 5 mm, up to 80 mm
            "foot_height_m": (0.003, 0.006),
            "stem_radius_m": (0.0035, 0.0050),  # ISO 3591: 9 +- 1 mm, down to 7 mm
            "stem_height_m": (0.050, 0.090),  # ISO 3591: 55 +- 3 mm with the foot
            "bowl_bottom_radius_m": (0.018, 0.026),
            "bowl_top_radius_m": (0.030, 0.042),  # ISO 3591: 65 +- 2 mm widest
            "bowl_height_m": (0.075, 0.105),  # ISO 3591: 100 +- 2 mm
        },
        _dims_only,
    ),
}


def split_of(variant: int) -> str:
    """``train`` or ``held_out``: which split a variant id belongs to.

    Raises:
        ValueError: an id in neither split.
    """
    for name, ids in SPLITS.items():
        if variant in ids:
            return name
    raise ValueError(
        f"variant {variant!r} is in no split; valid: "
        + ", ".join(f"{n} {r.start}-{r.stop - 1}" for n, r in SPLITS.items())
    )


def draw(name: str, variant: int) -> dict[str, float]:
    """The family's raw draw (dimensions and fractions) of one variant."""
    if name not in FAMILIES:
        raise ValueError(f"no variant family for {name!r}; valid: {', '.join(FAMILIES)}")
    split_of(variant)
    # crc32, not hash(): the same on every run and machine.
    rng = np.random.default_rng([_FAMILY_SEED, zlib.crc32(name.encode()), variant])
    family = FAMILIES[name]
    return {key: float(rng.uniform(lo, hi)) for key, (lo, hi) in family.ranges.items()}


def variant_dims(name: str, variant: int) -> dict[str, float]:
    """The dimensions (``geometry.objects.make`` keywords, metres) of one variant.

    Raises:
        ValueError: an unknown class or a variant id in no split.
    """
    raw = draw(name, variant)
    return FAMILIES[name].derive(raw)


def make_variant(name: str, variant: int) -> objects.ObjectModel:
    """Variant ``variant`` of class ``name`` as an object model."""
    return objects.make(name, **variant_dims(name, variant))
