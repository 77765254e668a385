"""The objects of the simulator (four household ones and the calibration cylinder), built from proximity-field primitives.

Shared by the simulator (rendering contact) and the pose estimator (fitting): one
description of each object. Every object lives in its geometry frame G (docs/design.md
``object``): symmetry axis on z, origin at half of the total height, metres.

    model = make("mug", radius_m=0.045)
    phi = model.field.value(points_in_object)
    lo, hi = model.bounds_m()

Dimensions are typical household sizes (a 95 mm mug, a 0.5 l PET bottle, a square
bottle, a wine glass); any of them can be overridden by keyword. Each class's family of
variants (real dishware's spread of sizes) is ``geometry.variants``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.fields import Box, CappedCylinder, Capsule, Field, Frustum, Transformed, Union
from geometry.se3 import make_pose, rotation_about


@dataclass(frozen=True, kw_only=True)
class ObjectModel:
    """A known object: its name, class label, field in frame G and dimensions.

    Attributes:
        name: the registry name (``mug``, ``pet_bottle``, ...).
        class_label: the label the classifier uses for it.
        field: the proximity field in the object frame G.
        dims_m: the dimensions it was built from (metres).
        symmetric_about_z: true for bodies of revolution, whose yaw about z cannot be
            observed from contact.
    """

    name: str
    class_label: str
    field: Field
    dims_m: dict[str, float] = field(default_factory=dict)
    symmetric_about_z: bool = False

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min_xyz, max_xyz)`` in the object frame."""
        return self.field.bounds_m()

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` points on the object's outer surface, (n, 3), object frame."""
        return self.field.sample_surface(n, rng)


def _at(
    child: Field, *, z_m: float = 0.0, x_m: float = 0.0, rot: np.ndarray | None = None
) -> Field:
    return Transformed(child, make_pose(rot, np.array([x_m, 0.0, z_m])))


def _cylinder(d: dict[str, float]) -> tuple[Field, bool]:
    return CappedCylinder(d["radius_m"], d["height_m"]), True


def _mug(d: dict[str, float]) -> tuple[Field, bool]:
    r, h = d["radius_m"], d["height_m"]
    body = CappedCylinder(r, h)
    # Handle: a C loop of three capsules on +x (two horizontal arms, one upright grip),
    # centred ``handle_offset_m`` above the body's middle (negative: below).
    rad, reach, span = d["handle_radius_m"], d["handle_reach_m"], d["handle_span_m"]
    z_mid = d["handle_offset_m"]
    arm_len = reach
    arm_rot = rotation_about(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    x_mid = r + reach / 2 - rad
    arms = [
        _at(Capsule(rad, arm_len), x_m=x_mid, z_m=z_mid + s * span / 2, rot=arm_rot)
        for s in (-1, 1)
    ]
    grip = _at(Capsule(rad, span), x_m=r + reach - rad, z_m=z_mid)
    return Union([body, *arms, grip]), False


def _pet_bottle(d: dict[str, float]) -> tuple[Field, bool]:
    r, rn = d["radius_m"], d["neck_radius_m"]
    hb, hs, hn = d["body_height_m"], d["shoulder_height_m"], d["neck_height_m"]
    total = hb + hs + hn
    z0 = -total / 2
    parts = [
        _at(CappedCylinder(r, hb), z_m=z0 + hb / 2),
        _at(Frustum(r, rn, hs), z_m=z0 + hb + hs / 2),
        _at(CappedCylinder(rn, hn), z_m=z0 + hb + hs + hn / 2),
    ]
    return Union(parts), True


def _square_bottle(d: dict[str, float]) -> tuple[Field, bool]:
    w, hb = d["width_m"], d["body_height_m"]
    rn, hn = d["neck_radius_m"], d["neck_height_m"]
    total = hb + hn
    z0 = -total / 2
    parts = [
        _at(Box([w, w, hb]), z_m=z0 + hb / 2),
        _at(CappedCylinder(rn, hn), z_m=z0 + hb + hn / 2),
    ]
    return Union(parts), False


def _wine_glass(d: dict[str, float]) -> tuple[Field, bool]:
    hf, hs, hb = d["foot_height_m"], d["stem_height_m"], d["bowl_height_m"]
    total = hf + hs + hb
    z0 = -total / 2
    parts = [
        _at(CappedCylinder(d["foot_radius_m"], hf), z_m=z0 + hf / 2),
        _at(CappedCylinder(d["stem_radius_m"], hs), z_m=z0 + hf + hs / 2),
        _at(
            Frustum(d["bowl_bottom_radius_m"], d["bowl_top_radius_m"], hb),
            z_m=z0 + hf + hs + hb / 2,
        ),
    ]
    return Union(parts), True


_BUILDERS: dict[
    str, tuple[str, dict[str, float], Callable[[dict[str, float]], tuple[Field, bool]]]
] = {
    "mug": (
        "mug",
        {
            "radius_m": 0.040,
            "height_m": 0.095,
            "handle_radius_m": 0.006,
            "handle_reach_m": 0.032,
            "handle_span_m": 0.055,
            "handle_offset_m": 0.0,
        },
        _mug,
    ),
    "pet_bottle": (
        "pet_bottle",
        {
            "radius_m": 0.033,
            "body_height_m": 0.150,
            "shoulder_height_m": 0.040,
            "neck_radius_m": 0.013,
            "neck_height_m": 0.020,
        },
        _pet_bottle,
    ),
    "square_bottle": (
        "square_bottle",
        {"width_m": 0.060, "body_height_m": 0.160, "neck_radius_m": 0.013, "neck_height_m": 0.030},
        _square_bottle,
    ),
    # A plain cylinder of known radius: the calibration object (perception.calibration).
    "cylinder": ("cylinder", {"radius_m": 0.030, "height_m": 0.160}, _cylinder),
    "wine_glass": (
        "wine_glass",
        {
            "foot_radius_m": 0.035,
            "foot_height_m": 0.005,
            "stem_radius_m": 0.004,
            "stem_height_m": 0.070,
            "bowl_bottom_radius_m": 0.022,
            "bowl_top_radius_m": 0.040,
            "bowl_height_m": 0.085,
        },
        _wine_glass,
    ),
}

CALIBRATION_OBJECTS = ("cylinder",)
# Dimensions that are positions, not sizes: any finite value (the others must be > 0).
SIGNED_DIMS = frozenset({"handle_offset_m"})
# The objects of the tasks (classes, datasets, pose fits); ``make`` builds these and the
# calibration objects.
NAMES: tuple[str, ...] = tuple(n for n in _BUILDERS if n not in CALIBRATION_OBJECTS)


def make(name: str, **overrides: Any) -> ObjectModel:
    """Build one of the simulator's objects, optionally overriding dimensions.

    Args:
        name: one of :data:`NAMES` or :data:`CALIBRATION_OBJECTS`.
        **overrides: dimension names of that object (metres), e.g. ``radius_m=0.045``.

    Raises:
        ValueError: an unknown name, an unknown dimension, or a non-positive one.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown object {name!r}; valid: {', '.join(_BUILDERS)}")
    label, defaults, build = _BUILDERS[name]
    unknown = sorted(set(overrides) - set(defaults))
    if unknown:
        raise ValueError(f"{name}: unknown dimension(s) {unknown}; valid: {sorted(defaults)}")
    dims = {**defaults, **{k: float(v) for k, v in overrides.items()}}
    for key, value in dims.items():
        if key in SIGNED_DIMS and not np.isfinite(value):
            raise ValueError(f"{name}: {key} must be finite, got {value}")
        if key not in SIGNED_DIMS and not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"{name}: {key} must be > 0, got {value}")
    fld, symmetric = build(dims)
    return ObjectModel(
        name=name, class_label=label, field=fld, dims_m=dims, symmetric_about_z=symmetric
    )
