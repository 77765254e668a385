"""Planar displacement fields: the least-squares rotation of a 2D field about its centroid.

Used by the shear estimate (``perception.shear``) and by the simulator's ground truth of
a shear (``sim.material_flow``), so both score a twist the same way.
"""

from __future__ import annotations

import math

import numpy as np


def rotation_about_centroid(
    x: np.ndarray, y: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[float, bool]:
    """Least-squares rotation angle of a 2D displacement field about its centroid.

    ``sin(theta) = sum(r x d) / sum(|r|^2)`` with ``r`` the positions and ``d`` the
    displacements relative to their means: half the field's curl for an affine field
    over an isotropic region, exactly ``sin(theta)`` for a rigid rotation.

    Args:
        x, y: 1D float64 positions (any unit).
        dx, dy: 1D float64 displacements (same unit).

    Returns:
        ``(theta_rad, defined)``; ``(0.0, False)`` when fewer than 3 points or no spread.
    """
    n = x.shape[0]
    if n < 3:
        return 0.0, False
    sx, sy, sdx, sdy = x.sum(), y.sum(), dx.sum(), dy.sum()
    # Sums of products (BLAS dots), then the centroid terms: one pass over the data.
    spread = float(np.dot(x, x) + np.dot(y, y) - (sx * sx + sy * sy) / n)
    cross = float(np.dot(x, dy) - np.dot(y, dx) - (sx * sdy - sy * sdx) / n)
    if not (math.isfinite(spread) and math.isfinite(cross) and spread > 1e-12 * n):
        return 0.0, False
    sine = cross / spread
    return math.asin(min(1.0, max(-1.0, sine))), True
