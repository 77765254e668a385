"""A toy tactile dataset: one indentation shape per class on a noisy bubble.

Not a simulator: a few lines that make small images whose classes differ the way the
real ones do (the shape of the contact), so tests and ``--quick`` benchmarks can train,
save and evaluate a model in seconds. Per class, the indentation is a disc, a bar, a
square or a ring; position, size and depth vary per grasp, noise per frame. IR is the
amplitude of a ToF camera, falling with the square of the distance.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from perception.classify.dataset import DatasetWriter, GraspBuffer

SHAPES = ("disc", "bar", "square", "ring")
BASE_DEPTH_M = 0.06
NOISE_M = 0.0007


def _indentation(shape: str, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A 0..1 indentation mask of ``shape``, placed and sized at random."""
    yy: np.ndarray
    xx: np.ndarray
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    cy, cx = h * rng.uniform(0.35, 0.65), w * rng.uniform(0.35, 0.65)
    r = min(h, w) * rng.uniform(0.2, 0.3)
    dy, dx = yy - cy, xx - cx
    if shape == "disc":
        return (np.hypot(dy, dx) < r).astype(float)
    if shape == "bar":
        return ((np.abs(dx) < r * 0.35) & (np.abs(dy) < h * 0.45)).astype(float)
    if shape == "square":
        return ((np.abs(dx) < r * 0.9) & (np.abs(dy) < r * 0.9)).astype(float)
    if shape == "ring":
        d = np.hypot(dy, dx)
        return ((d < r * 1.1) & (d > r * 0.6)).astype(float)
    raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")


def toy_frame(
    shape: str, image_shape: tuple[int, int], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """One bubble's (depth_m float32 with a few NaN, ir uint16) with a ``shape`` contact."""
    h, w = image_shape
    yy, xx = np.mgrid[0:h, 0:w]
    dome = 0.01 * (((yy - h / 2) / h) ** 2 + ((xx - w / 2) / w) ** 2)
    depth = BASE_DEPTH_M + dome - rng.uniform(0.008, 0.015) * _indentation(shape, h, w, rng)
    depth = depth + rng.normal(0, NOISE_M, size=depth.shape)
    depth[rng.random(depth.shape) < 0.01] = np.nan
    ir = np.where(np.isnan(depth), 0, 4000.0 * (BASE_DEPTH_M / np.nan_to_num(depth, nan=1.0)) ** 2)
    return depth.astype(np.float32), ir.astype(np.uint16)


def write_toy_dataset(
    root: str | Path,
    *,
    classes: Sequence[str] = ("mug", "pet_bottle", "square_bottle", "wine_glass"),
    grasps_per_class: int = 4,
    frames_per_grasp: int = 4,
    image_shape: tuple[int, int] = (24, 32),
    seed: int = 0,
) -> Path:
    """Write a toy dataset (same format as the real one) and return its directory.

    Class ``i`` gets shape ``SHAPES[i % 4]``; each grasp fixes the contacts, each frame
    adds noise. Deterministic per ``seed``.
    """
    rng = np.random.default_rng(seed)
    writer = DatasetWriter(
        root,
        classes=classes,
        seeds={"toy": seed},
        scene={"generator": "perception.classify.synthetic", "image_shape": list(image_shape)},
        resume=False,
    )
    grasp_id = 0
    for _ in range(grasps_per_class):
        for label, name in enumerate(classes):
            shape = SHAPES[label % len(SHAPES)]
            grasp_seed = int(rng.integers(2**31))
            buffer = GraspBuffer()
            for frame in range(frames_per_grasp):
                # Same placement within a grasp (same seed), fresh noise per frame.
                placement = np.random.default_rng(grasp_seed)
                left_d, left_ir = toy_frame(shape, image_shape, placement)
                right_d, right_ir = toy_frame(shape, image_shape, placement)
                noise = rng.normal(0, NOISE_M, size=(2, *image_shape)).astype(np.float32)
                buffer.add(left_d + noise[0], right_d + noise[1], left_ir, right_ir, frame)
            writer.write_grasp(grasp_id, name, buffer, {"shape": shape, "seed": grasp_seed})
            grasp_id += 1
    return Path(root)
