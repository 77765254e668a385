"""From two bubbles' ToF frames to the network's input tensor.

As in the paper (tactile classification section), the left and right images are placed
side by side and the pair is resized to one square image (``input_px`` x ``input_px``,
224 in the paper; 112 is about four times cheaper). The modality picks the channels:
``depth`` (1), ``ir`` (1) or ``both`` (2, depth first).

Normalisation, per channel:

* depth: metres mapped with a fixed centre and scale (55 mm and 10 mm: the simulated
  camera sees the membrane at 3-8 cm, the real one works at 4-11 cm, docs/facts.md), so an
  indentation means the same value in every frame; values are clipped to +-4. An invalid
  (NaN) pixel becomes ``invalid_depth_m``: the ToF's 40 mm minimum range. Inside the
  bubble a pixel is lost mostly where an object pushes the membrane nearer than that
  (a deep imprint's hole); read as "at the minimum range", a hole looks like the dent it
  is, and a shallower imprint that stays readable looks nearly the same
  (docs/classifier.md, "Invalid pixels"). Checkpoints from before that read a hole as
  the centre (55 mm, input 0); a checkpoint stores all three figures and one without
  ``invalid_depth_m`` loads with the centre.
* IR: amplitude standardised per frame over the valid pixels of both bubbles (mean and
  standard deviation), clipped to +-4: amplitude scales with exposure and distance, a
  viewer stretches it the same way (mean +- 2 sigma, docs/facts.md).

Optionally (``imprint_depth_m > 0``, with each bubble's no-contact frame, ``free``), the
imprint's shape without its scale: before the steps above, each bubble's deformation
(its free frame's depth minus this frame's, towards the camera; a hole at the minimum
range) is scaled so that its 99th percentile is ``imprint_depth_m``, and its IR change
from the free frame so that the 99th percentile of its size is ``imprint_ir``; the frame the network sees is the
free frame plus the scaled changes. A membrane that stops the jaws wider and dents less
deep (``world.mujoco``'s taut shell, docs/mujoco.md) then gives the input a deeper dent of
the same shape would. ``imprint_depth_m = 0`` is the input above, unscaled.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

MODALITIES = ("depth", "ir", "both")
DEPTH_CENTER_M = 0.055
DEPTH_SCALE_M = 0.01
# The ToF's minimum range (``sim.rig``'s camera ``min_range_m``): what an invalid pixel is.
INVALID_DEPTH_M = 0.04
CLIP = 4.0
# The quantile of a bubble's deformation (and IR change) that is scaled to the canonical
# imprint, and the least deformation (IR change) that is scaled at all: below it a bubble
# is all but untouched and its change mostly noise (the ToF's is about 1 mm).
IMPRINT_QUANTILE = 0.99
IMPRINT_FLOOR_M = 0.002
IMPRINT_FLOOR_IR = 20.0
FREE_FIELDS = ("depth_left_m", "depth_right_m", "ir_left", "ir_right")


def channels(modality: str) -> int:
    """Input channels for a modality.

    Raises:
        ValueError: unknown modality.
    """
    check_modality(modality)
    return 2 if modality == "both" else 1


def check_modality(modality: str) -> None:
    """Raise ``ValueError`` naming the valid modalities if ``modality`` is not one."""
    if modality not in MODALITIES:
        raise ValueError(f"modality must be one of {MODALITIES}, got {modality!r}")


@dataclass(frozen=True, kw_only=True, eq=False)
class FreeBubble:
    """Each bubble's frame with nothing touching it: depth (m, NaN invalid) and IR."""

    depth_left_m: np.ndarray
    depth_right_m: np.ndarray
    ir_left: np.ndarray
    ir_right: np.ndarray

    def __post_init__(self) -> None:
        shape = self.depth_left_m.shape
        for name in ("depth_right_m", "ir_left", "ir_right"):
            if getattr(self, name).shape != shape:
                raise ValueError(
                    f"free bubble {name} has shape {getattr(self, name).shape}, "
                    f"depth_left_m {shape}"
                )

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], where: str) -> FreeBubble:
        """From arrays named as the fields, rounded to float16 (as a checkpoint stores
        them, so that training and inference see the same frames).

        Raises:
            ValueError: a missing array, naming it and ``where`` they came from.
        """
        missing = [n for n in FREE_FIELDS if n not in arrays]
        if missing:
            raise ValueError(f"{where}: no {missing[0]} (a free bubble needs {list(FREE_FIELDS)})")
        return cls(
            **{n: np.asarray(arrays[n]).astype(np.float16).astype(np.float32) for n in FREE_FIELDS}
        )

    def same(self, other: FreeBubble | None) -> bool:
        """Whether ``other`` holds the same frames (NaN equal to NaN)."""
        return other is not None and all(
            np.array_equal(getattr(self, n), getattr(other, n), equal_nan=True) for n in FREE_FIELDS
        )


@dataclass(frozen=True, kw_only=True)
class InputSpec:
    """What a model expects: channels from ``modality``, a square ``input_px`` image;
    with ``imprint_depth_m > 0`` each imprint scaled to that depth against ``free``."""

    modality: str
    input_px: int
    depth_center_m: float = DEPTH_CENTER_M
    depth_scale_m: float = DEPTH_SCALE_M
    invalid_depth_m: float = INVALID_DEPTH_M
    imprint_depth_m: float = 0.0
    imprint_ir: float = 0.0
    free: FreeBubble | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        check_modality(self.modality)
        if self.input_px < 32:
            raise ValueError(f"input_px must be >= 32, got {self.input_px}")
        if not self.depth_scale_m > 0:
            raise ValueError(f"depth_scale_m must be > 0, got {self.depth_scale_m}")
        if not self.invalid_depth_m > 0:
            raise ValueError(f"invalid_depth_m must be > 0, got {self.invalid_depth_m}")
        if self.imprint_depth_m < 0 or self.imprint_ir < 0:
            raise ValueError(
                f"imprint_depth_m and imprint_ir must be >= 0, got "
                f"{self.imprint_depth_m} and {self.imprint_ir}"
            )
        if (self.imprint_depth_m > 0) != (self.imprint_ir > 0):
            raise ValueError("imprint_depth_m and imprint_ir are both > 0 or both 0")
        if self.imprint_depth_m > 0 and self.free is None:
            raise ValueError("an imprint scale (imprint_depth_m > 0) needs the free bubble")

    @property
    def channels(self) -> int:
        return channels(self.modality)


def _side_by_side(left: np.ndarray, right: np.ndarray, input_px: int) -> np.ndarray:
    if left.shape != right.shape:
        raise ValueError(f"left and right images differ in shape: {left.shape} vs {right.shape}")
    pair = np.concatenate([left, right], axis=1).astype(np.float32, copy=False)
    # INTER_AREA averages the pixels a target pixel covers: the right filter to shrink.
    return cv2.resize(pair, (input_px, input_px), interpolation=cv2.INTER_AREA)


def normalise_depth(depth_m: np.ndarray, spec: InputSpec) -> np.ndarray:
    """Depth in metres (NaN invalid) to the network's scale; NaN is ``invalid_depth_m``."""
    out = (depth_m.astype(np.float32) - spec.depth_center_m) / spec.depth_scale_m
    invalid = (spec.invalid_depth_m - spec.depth_center_m) / spec.depth_scale_m
    out = np.nan_to_num(out, nan=invalid, posinf=CLIP, neginf=-CLIP)
    clipped: np.ndarray = np.clip(out, -CLIP, CLIP, out=out)
    return clipped


def normalise_ir(ir_left: np.ndarray, ir_right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both bubbles' IR amplitudes standardised together (0 where amplitude is 0)."""
    left = ir_left.astype(np.float32)
    right = ir_right.astype(np.float32)
    valid = np.concatenate([left[left > 0], right[right > 0]])
    if valid.size < 2:
        return np.zeros_like(left), np.zeros_like(right)
    mean = float(valid.mean())
    std = max(float(valid.std()), 1.0)
    out = []
    for image in (left, right):
        z = np.where(image > 0, (image - mean) / std, 0.0).astype(np.float32)
        out.append(np.clip(z, -CLIP, CLIP, out=z))
    return out[0], out[1]


def _scaled(change: np.ndarray, size: np.ndarray, target: float, floor: float) -> np.ndarray:
    """``change`` scaled so that the :data:`IMPRINT_QUANTILE` of ``size`` (its finite
    values) is ``target``; below ``floor`` the scale stays that of ``floor``."""
    finite = size[np.isfinite(size)]
    q = float(np.quantile(finite, IMPRINT_QUANTILE)) if finite.size else 0.0
    return change * np.float32(target / max(q, floor))


def scaled_imprint(
    spec: InputSpec,
    depth_m: np.ndarray,
    ir: np.ndarray,
    free_depth_m: np.ndarray,
    free_ir: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One bubble's frame with its imprint scaled to ``spec``'s canonical size (module
    docstring): depth (m; NaN where the free frame has none) and IR (0 where invalid)."""
    depth = np.where(np.isnan(depth_m), spec.invalid_depth_m, depth_m).astype(np.float32)
    dent = free_depth_m - depth  # towards the camera: > 0
    dent = _scaled(dent, dent, spec.imprint_depth_m, IMPRINT_FLOOR_M)
    valid = (ir > 0) & (free_ir > 0)
    change = np.where(valid, ir.astype(np.float32) - free_ir, np.nan).astype(np.float32)
    change = _scaled(change, np.abs(change), spec.imprint_ir, IMPRINT_FLOOR_IR)
    out_ir = np.where(valid, np.maximum(free_ir + change, 1.0), 0.0).astype(np.float32)
    return (free_depth_m - dent).astype(np.float32), out_ir


def frame_input(
    spec: InputSpec,
    *,
    depth_left_m: np.ndarray | None = None,
    depth_right_m: np.ndarray | None = None,
    ir_left: np.ndarray | None = None,
    ir_right: np.ndarray | None = None,
) -> np.ndarray:
    """One network input ``(channels, input_px, input_px)`` float32 from one frame pair.

    Only the arrays the modality needs must be given.

    Raises:
        ValueError: a needed array is missing, or left and right differ in shape.
    """
    if spec.imprint_depth_m > 0:
        assert spec.free is not None  # InputSpec checks it
        if depth_left_m is None or depth_right_m is None or ir_left is None or ir_right is None:
            raise ValueError("the imprint scale needs depth and IR of both bubbles")
        free = spec.free
        depth_left_m, ir_left = scaled_imprint(
            spec, depth_left_m, ir_left, free.depth_left_m, free.ir_left
        )
        depth_right_m, ir_right = scaled_imprint(
            spec, depth_right_m, ir_right, free.depth_right_m, free.ir_right
        )
    planes = []
    if spec.modality in ("depth", "both"):
        if depth_left_m is None or depth_right_m is None:
            raise ValueError(f"modality {spec.modality!r} needs depth_left_m and depth_right_m")
        planes.append(
            _side_by_side(
                normalise_depth(depth_left_m, spec),
                normalise_depth(depth_right_m, spec),
                spec.input_px,
            )
        )
    if spec.modality in ("ir", "both"):
        if ir_left is None or ir_right is None:
            raise ValueError(f"modality {spec.modality!r} needs ir_left and ir_right")
        left, right = normalise_ir(ir_left, ir_right)
        planes.append(_side_by_side(left, right, spec.input_px))
    return np.stack(planes, axis=0)
