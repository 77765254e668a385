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
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

MODALITIES = ("depth", "ir", "both")
DEPTH_CENTER_M = 0.055
DEPTH_SCALE_M = 0.01
# The ToF's minimum range (``sim.rig``'s camera ``min_range_m``): what an invalid pixel is.
INVALID_DEPTH_M = 0.04
CLIP = 4.0


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


@dataclass(frozen=True, kw_only=True)
class InputSpec:
    """What a model expects: channels from ``modality``, a square ``input_px`` image."""

    modality: str
    input_px: int
    depth_center_m: float = DEPTH_CENTER_M
    depth_scale_m: float = DEPTH_SCALE_M
    invalid_depth_m: float = INVALID_DEPTH_M

    def __post_init__(self) -> None:
        check_modality(self.modality)
        if self.input_px < 32:
            raise ValueError(f"input_px must be >= 32, got {self.input_px}")
        if not self.depth_scale_m > 0:
            raise ValueError(f"depth_scale_m must be > 0, got {self.depth_scale_m}")
        if not self.invalid_depth_m > 0:
            raise ValueError(f"invalid_depth_m must be > 0, got {self.invalid_depth_m}")

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
