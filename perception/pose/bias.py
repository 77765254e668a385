"""The bias that noise along the cameras' rays leaves in the fit, predicted from the rays.

Each bubble's camera looks at its membrane obliquely (about 55 degrees from the plate's
normal), so depth noise moves a point along the surface as well as across it; where the
surface curves, or the noise crosses an edge or a rim, a point's residual and its
Jacobian row change together and their product does not average out. The fit's minimum
then sits off the truth by ``-H^-1 E[sum r_i J_i]`` (:func:`ray_bias`), and
:func:`unbiased` moves the estimate to where the fit's gradient equals that bias. The
judgement (``judge.uncertainty``) applies the move and carries what the prediction misses.
"""

from __future__ import annotations

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose.problem import residuals_and_jacobian

#: Points already in the object frame (``ray_bias`` evaluates rows there).
IDENTITY = np.eye(4)
#: Gauss-Hermite nodes of the average over the noise along a ray (``ray_bias``).
NODES = 7
#: The rays' bias is summed over at most this many points, scaled to all (``ray_bias``).
BIAS_POINTS = 2000
#: Newton steps toward the pose where the fit's gradient equals the rays' bias, and the
#: step (in statistical standard deviations of the fit) under which they stop
#: (``unbiased``).
UNBIAS_STEPS = 4
UNBIAS_TOL = 0.1
#: Newton steps along the ray back onto the surface (``ray_bias``).
SURFACE_STEPS = 3


def ray_bias(
    fld: Field,
    object_from_tool: np.ndarray,
    points_in_tool: np.ndarray,
    rays_in_tool: np.ndarray,
    r: np.ndarray,
    jac: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray, float]:
    """The expected gradient of the half cost, ``E[sum_i r_i J_i]`` (6,), that noise along
    the camera rays leaves at the true pose (module docstring), the mean residual it
    leaves there (at a box's corner at 3 mm noise about +0.2 mm: a point pushed inside
    near an edge is nearer the other face), and the gradient's parts (6, 6) from the
    points on each face (their surface's normal nearest each of the object's axes, -x,
    +x, -y, ...; they sum to it), and the ray noise. Each point is moved back
    along its ray onto the surface (Newton steps ``r / (g . d)``), and the product of
    its residual and Jacobian row is averaged over Gaussian noise along the ray there
    (Gauss-Hermite, ``NODES`` nodes), less that product without noise: no expansion in
    the noise, so edges and rims the noise crosses count as they are. The ray noise
    ``sigma^2`` is ``sum (r - mean r)^2 / sum (g . d)^2``. Every k-th point stands for
    its neighbours, so that at most ``BIAS_POINTS`` are evaluated."""
    stride = -(-len(r) // BIAS_POINTS)  # every stride-th point: at most BIAS_POINTS
    rot = object_from_tool[:3, :3]
    q = points_in_tool[::stride] @ rot.T + object_from_tool[:3, 3]
    d = rays_in_tool[::stride] @ rot.T
    r, jac = r[::stride], jac[::stride]
    along = np.sum(jac[:, :3] * d, axis=1)
    spread = r - np.mean(r)  # a model of the wrong size offsets them all: not noise
    sigma = float(np.sqrt(float(spread @ spread) / max(float(along @ along), 1e-12)))
    # Back along the ray onto the surface (Newton steps; no further than three sigma in
    # all, for a ray that grazes it): one step leaves the point inside a curved surface
    # by about the bias sought.
    surface, value, grad = q, r, jac[:, :3]
    travelled = np.zeros(len(q))
    for _ in range(SURFACE_STEPS):
        slope = np.sum(grad * d, axis=1)
        step = value / np.where(np.abs(slope) > 1e-3, slope, np.inf)
        travelled = np.clip(travelled + step, -3 * sigma, 3 * sigma)
        surface = q - travelled[:, None] * d
        value, grad = fld.value_and_grad(surface)
    nodes, weights = np.polynomial.hermite_e.hermegauss(NODES)
    weights = weights / weights.sum()
    # Only what the noise adds: where the model misses the points (an object of another
    # size) the point cannot be moved onto the surface, and its own residual is no bias.
    value, rows = residuals_and_jacobian(fld, IDENTITY, surface)
    each = -(value[:, None] * rows)
    mean = -float(np.mean(value))
    for e, w in zip(sigma * nodes, weights, strict=True):
        value, rows = residuals_and_jacobian(fld, IDENTITY, surface + e * d)
        each += w * (value[:, None] * rows)
        mean += w * float(np.mean(value))
    axis = np.argmax(np.abs(grad), axis=1)
    face = 2 * axis + (grad[np.arange(len(axis)), axis] > 0)
    parts = np.stack([each[face == f].sum(axis=0) for f in range(6)])
    parts *= len(points_in_tool) / len(q)
    bias: np.ndarray = parts.sum(axis=0)
    return bias, mean, parts, sigma


def unbiased(
    fld: Field,
    object_from_tool: np.ndarray,
    points_in_tool: np.ndarray,
    rays_in_tool: np.ndarray,
    r: np.ndarray,
    jac: np.ndarray,
    twist: np.ndarray,
    h_inv: np.ndarray,
    cov: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray, float]:
    """The shift from the fit's minimum ``object_from_tool`` (its residuals ``r`` and
    Jacobian ``jac`` there, as the caller has them) to the pose where the fit's
    gradient equals the bias the rays predict (:func:`ray_bias`): at the truth the
    gradient is that bias on average, so this is the estimate with the bias undone.
    Returns the shift (``(k,)``, in the coordinates of ``twist``, (6, k): coordinates to
    left twist), the mean residual the noise leaves at the truth, each face's part of
    the predicted bias in those coordinates (``(6, k)``: the caller weighs it with the
    curvature its spread takes), and the noise along the rays. Newton steps with
    ``h_inv`` (the inverse measured curvature along those coordinates) and the data's
    gradient at the pose reached, at most ``UNBIAS_STEPS`` and until a step is under
    ``UNBIAS_TOL`` standard deviations (``cov``, the statistical covariance in those
    coordinates): the one step from the minimum of the round before was off where the
    offset spans several standard deviations and the cost is not quadratic across it (a
    box's corner at 3 mm noise: 0.4 mm, five of them)."""
    bias, noise_mean, parts, sigma = ray_bias(
        fld, object_from_tool, points_in_tool, rays_in_tool, r, jac
    )
    pose = object_from_tool
    for _ in range(UNBIAS_STEPS):
        step = h_inv @ (twist.T @ (bias - jac.T @ r))
        pose = se3.exp_se3(twist @ step) @ pose
        if float(step @ np.linalg.solve(cov, step)) < UNBIAS_TOL**2:
            break
        r, jac = residuals_and_jacobian(fld, pose, points_in_tool)
    shift: np.ndarray = np.linalg.lstsq(
        twist, se3.log_se3(pose @ se3.invert(object_from_tool)), rcond=None
    )[0]
    return shift, noise_mean, (twist.T @ parts.T).T, sigma
