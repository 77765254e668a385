"""The cloud before a solve: finite rows, a fixed subsample, its noise measured from the
data alone, and the camera rays the noise lies along."""

from __future__ import annotations

import numpy as np

from geometry.gripper import DEFAULT_GRIPPER, GripperGeometry


def clean_cloud(
    points: np.ndarray, bubble: np.ndarray | None = None, max_points: int | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Finite rows of an (N, 3) cloud as float64, and the bubble of each (``None`` when
    not given or not one per row), subsampled to ``max_points`` (fixed seed).

    Subsampling with a fixed generator keeps a repeated solve on the same patch
    deterministic.
    """
    raw = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(raw), axis=1)
    sides = np.asarray(bubble)[finite] if bubble is not None and len(bubble) == len(raw) else None
    pts = raw[finite]
    if max_points is not None and len(pts) > max_points:
        idx = np.sort(np.random.default_rng(0).choice(len(pts), size=max_points, replace=False))
        pts = pts[idx]
        sides = sides[idx] if sides is not None else None
    return pts, sides


def clean_points(points: np.ndarray, max_points: int | None = None) -> np.ndarray:
    """:func:`clean_cloud` without the bubbles."""
    return clean_cloud(points, None, max_points)[0]


def estimate_noise_m(
    points: np.ndarray, *, sample: int = 1000, neighbours: int = 40, queries: int = 150
) -> float:
    """The depth noise of a cloud from the data alone: the median RMS of the residuals of
    local quadric fits (``neighbours`` nearest points around ``queries`` points, height
    over their principal plane, six coefficients), corrected for the fitted degrees of
    freedom. The cloud is first thinned to ``sample`` points, so a neighbourhood spans
    several millimetres whatever the point count (a dense cloud's tiny neighbourhoods
    would take 3 mm noise for curvature). Curvature is absorbed by the quadric, so a curved patch is not taken for
    noise; a neighbourhood across an edge is, and the median ignores the few there."""
    from scipy.spatial import cKDTree  # here, not at import: checking a graph need not pay

    pts = clean_points(points, sample)
    k = min(neighbours, len(pts))
    if k < 10:
        return 0.0
    rng = np.random.default_rng(0)
    centres = pts[rng.choice(len(pts), size=min(queries, len(pts)), replace=False)]
    _, idx = cKDTree(pts).query(centres, k=k)
    hood = pts[idx]  # (Q, k, 3)
    hood = hood - hood.mean(axis=1, keepdims=True)
    # Batched matrix products: several times faster than the equivalent einsums.
    _, vecs = np.linalg.eigh(hood.transpose(0, 2, 1) @ hood)
    local = hood @ vecs  # coordinates in the principal frame
    u, v, w = local[..., 2], local[..., 1], local[..., 0]  # w along the least spread
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)
    gram = design.transpose(0, 2, 1) @ design + 1e-18 * np.eye(6)
    coef = np.linalg.solve(gram, design.transpose(0, 2, 1) @ w[..., None])
    resid = w - (design @ coef)[..., 0]
    var = np.sum(resid * resid, axis=1) / (k - 6)
    return float(np.sqrt(np.median(var)))


def camera_rays(
    points: np.ndarray, bubble: np.ndarray | None, gripper: GripperGeometry = DEFAULT_GRIPPER
) -> np.ndarray | None:
    """Unit directions (N, 3) from each point's camera to the point, in the tool frame:
    the direction its depth noise lies along (``None`` without one bubble per point).

    Each bubble's plate is placed from its own points (the apex of its membrane at the
    innermost point it touches: ``cap_height_m`` outboard of it), so the opening need
    not be known; an error of a few millimetres turns the rays by a degree or two."""
    if bubble is None or len(bubble) != len(points) or not np.all(np.isin(bubble, (0, 1))):
        return None
    rays = np.empty_like(points)
    for k, side in enumerate(("left", "right")):
        sel = bubble == k
        if not np.any(sel):
            continue
        inner = float(np.min(points[sel, 0])) if k == 0 else -float(np.max(points[sel, 0]))
        plate_x = inner + gripper.bubble.cap_height_m
        width = 2.0 * (plate_x - gripper.plate_outset_m)
        rays[sel] = points[sel] - gripper.tool_from_sensor(side, width)[:3, 3]
    unit: np.ndarray = rays / np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    return unit
