"""The dots that leave the patch's rigid motion: a slip cue finer than the patch's means.

While a point of the membrane sticks to the object it moves with it, and the object is
rigid: over a short window the stuck part of the patch moves as one (a translation and
a turn about the plate's normal). A point that slides over the object does not: it
lags. The latex slides one point after the other from the rim in, so the share of the
patch whose recent motion leaves the stuck part's rigid motion is the share that slides
(the truth of slip on ``world.mujoco`` is that share of its material points), with no
stick limit in between: the shift per pascal at which a patch begins to slide spreads
with the object and the load's direction on a shell (docs/force.md), the share does not
need it.

The dots' flow is noisy pixel by pixel (about 0.1 mm from one frame to the next on a
membrane meshed at 12 mm): the velocities are taken over a few frames and averaged
over cells of a few millimetres before the fit; the fit is the rigid motion of the
cells that move most alike (half of them: the stuck part, while at most half slides);
a cell departs when its speed off that motion passes ``speed_m_per_s``.
"""

from __future__ import annotations

import numpy as np

MIN_CELLS = 4


def rigid_fit(positions: np.ndarray, velocity: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The weighted least-squares rigid motion (translation and turn about the weighted
    centroid) of a 2D velocity field, evaluated at ``positions`` ``(n, 2)``."""
    total = weight.sum()
    arm = positions - (positions * weight[:, None]).sum(0) / total
    across = np.stack([-arm[:, 1], arm[:, 0]], axis=1)
    mean = (velocity * weight[:, None]).sum(0) / total
    spread = float((weight * (across * across).sum(1)).sum())
    turn = (
        float((weight * ((velocity - mean) * across).sum(1)).sum()) / spread if spread > 0 else 0.0
    )
    out: np.ndarray = mean + turn * across
    return out


def departing_share(
    positions_m: np.ndarray,
    velocity_m_per_s: np.ndarray,
    *,
    cell_m: float,
    speed_m_per_s: float,
    iterations: int = 3,
) -> float:
    """The share of the patch (by its dots) whose velocity leaves the stuck part's rigid
    motion by more than ``speed_m_per_s`` (module docstring); 0 with too few cells.

    Args:
        positions_m: the dots' tangential positions ``(n, 2)`` (tool y, z).
        velocity_m_per_s: their tangential velocities ``(n, 2)`` over the window.
        cell_m: the cells' side over which the dots' velocities are averaged.
        speed_m_per_s: a cell departs when its speed off the fit passes this.
        iterations: refits on the half of the cells nearest the fit.
    """
    if len(positions_m) == 0:
        return 0.0
    grid = np.floor(positions_m / cell_m).astype(np.int64)
    grid -= grid.min(axis=0)
    key = grid[:, 0] * (int(grid[:, 1].max()) + 1) + grid[:, 1]
    # The cells a dot falls in, numbered densely (a count and a lookup, not a sort).
    count = np.bincount(key)
    used = np.flatnonzero(count)
    if len(used) < MIN_CELLS:
        return 0.0
    number = np.zeros(len(count), np.int64)
    number[used] = np.arange(len(used))
    cell = number[key]
    dots = count[used].astype(np.float64)

    def mean(values: np.ndarray) -> np.ndarray:
        sums = [np.bincount(cell, values[:, i], len(used)) for i in range(2)]
        return np.stack(sums, axis=1) / dots[:, None]

    velocity, where = mean(velocity_m_per_s), mean(positions_m)
    weight = dots.copy()
    for _ in range(iterations):
        off = np.linalg.norm(velocity - rigid_fit(where, velocity, weight), axis=1)
        weight = dots * ((off <= np.median(off)) + 1e-9)
    off = np.linalg.norm(velocity - rigid_fit(where, velocity, weight), axis=1)
    return float(dots[off > speed_m_per_s].sum() / dots.sum())
