"""The problem every pose solver shares: the unknown, the result, input checks, residuals.

The unknown is the paper's ``G X T``, here named ``object_from_tool`` (a 4x4 pose):
a point of the grasp cloud in the tool frame maps into the object frame G, where the
proximity field ``phi`` is evaluated. The cost is ``sum_i phi(object_from_tool p_i)^2``
(paper, eq. "proximity pose optimization"). Results carry ``tool_from_object`` too
(the inverse, what ``PoseEstimate`` stores), so no caller inverts by hand.

Perturbations are on the left, in the object frame: ``X <- exp(xi) X`` with
``xi = (tx, ty, tz, rx, ry, rz)``. The residual Jacobian row of point ``q = X p`` is
``[g, q x g]`` with ``g = grad phi(q)``. In these coordinates the symmetries of the
object are coordinate axes: a body of revolution cannot be yawed about z, a cylinder
seen only on its side cannot be moved along z; their columns of the Jacobian are zero
and ``observable`` reports them as ``False``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry import se3
from geometry.fields import Field

DOF_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True, kw_only=True)
class FitResult:
    """One solve: the pose both ways, how well it fits and how the solver got there.

    Attributes:
        object_from_tool: the estimate (paper's G X T), 4x4.
        residual_rms_m: RMS of the field values at the estimate (metres).
        cost: sum of squared field values (m^2).
        iterations: solver iterations (summed over re-seeds when recovering).
        status: from a local solver ``ok`` (converged), ``not_converged`` (stopped by
            its iteration limit or a numerical failure; the pose is its last iterate) or
            ``failed``; from the estimator ``ok``, ``recovered`` (the first seed's minimum
            lost to another seed's), ``suspect`` (see ``message``: the observable
            directions are not determined to the estimator's tolerance, the fit is
            worse than the noise allows or biased, another minimum that differs in an
            observable direction fits about as well, too few directions are observable,
            or the answer is not at the minimum of the fit), ``no_patch``
            (too few points, or no spread in 3-D: the prior is returned) or ``failed``.
        solve_secs: wall time of the solve.
        points_used: points after dropping non-finite ones and subsampling.
        observable: per ``(tx, ty, tz, rx, ry, rz)`` in the object frame.
        solver: which solver produced it.
        seeds_tried: how many starting poses were solved from.
        message: why the status is not ``ok`` (the solver's own verdict for IPOPT).
        noise_m: the depth noise the acceptance test used (estimated from the data
            unless configured); 0 when not computed.
        dims_m: fitted dimensions (``radius_m``, ``height_m``), empty unless fitted.
        residual_mean_m: the mean of the field values at the estimate (its bias).
        covariance: (6, 6) covariance of the estimate's left twist ``(tx, ty, tz, rx,
            ry, rz)`` in the object frame (metres, radians), zero along unobservable
            directions (``judge.uncertainty``); zeros when not computed.
        region95_deg, region95_m: the largest rotation and the largest displacement of
            the object's origin within the 95% region; 0 when not computed.
        alternatives: other minima that fit as well and agree with the estimate on
            every observable direction (the patch cannot tell them apart), described;
            empty when there are none.
    """

    object_from_tool: np.ndarray
    residual_rms_m: float
    cost: float
    iterations: int
    status: str
    solve_secs: float
    points_used: int
    observable: tuple[bool, ...] = (False,) * 6
    solver: str = ""
    seeds_tried: int = 1
    message: str = ""
    noise_m: float = 0.0
    dims_m: dict[str, float] = field(default_factory=dict)
    residual_mean_m: float = 0.0
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    region95_deg: float = 0.0
    region95_m: float = 0.0
    alternatives: str = ""

    @property
    def tool_from_object(self) -> np.ndarray:
        """The inverse of :attr:`object_from_tool` (what ``PoseEstimate`` carries)."""
        return se3.invert(self.object_from_tool)


MIN_POINTS = 6  # six unknowns
MIN_SPREAD_M = 1e-5  # the smallest principal standard deviation a cloud must reach


def principal_spreads_m(points: np.ndarray) -> np.ndarray:
    """The principal standard deviations of finite (N, 3) points, largest first."""
    centred = points - points.mean(axis=0)
    # Eigenvalues of the 3x3 scatter: far cheaper than an SVD of (N, 3).
    return np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred / len(points))[::-1], 0.0))


def flatness_m(points: np.ndarray) -> float:
    """The smallest principal standard deviation of finite (N, 3) points: about the noise
    for a single flat patch."""
    return float(principal_spreads_m(points)[2])


def spread_problem(points: np.ndarray, min_spread_m: float = MIN_SPREAD_M) -> str:
    """Why finite (N, 3) points cannot fix a pose ("" if they can): too few, all at one
    point, on a line or on a plane (principal standard deviations under ``min_spread_m``)."""
    n = len(points)
    if n < MIN_POINTS:
        return f"{n} finite points, at least {MIN_POINTS} needed"
    std = principal_spreads_m(points)
    shape = ("at one point", "on a line", "on a plane")
    for k, name in enumerate(shape):
        if std[k] < min_spread_m:
            return f"the points lie {name} (principal spreads {np.round(std * 1e3, 4)} mm)"
    return ""


def check_problem(
    points: np.ndarray, object_from_tool: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The points and seed a local solver may trust, as float64; else a ``ValueError``.

    Points: (N, 3), all finite, spread in 3-D (:func:`spread_problem`). Seed: a finite
    rigid 4x4 (orthonormal rotation, determinant +1, last row 0 0 0 1, to 1e-6).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_in_tool must have shape (N, 3), got {pts.shape}")
    bad = int(np.sum(~np.all(np.isfinite(pts), axis=1)))
    if bad:
        raise ValueError(f"points_in_tool has {bad} non-finite row(s) of {len(pts)}")
    problem = spread_problem(pts)
    if problem:
        raise ValueError(f"points_in_tool: {problem}")
    check_rigid(object_from_tool, "object_from_tool")
    return pts, np.asarray(object_from_tool, dtype=np.float64)


def check_rigid(pose: np.ndarray, name: str) -> None:
    """``ValueError`` naming ``name`` unless ``pose`` is a finite rigid 4x4."""
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite 4x4, got shape {arr.shape}")
    rot = arr[:3, :3]
    err = float(np.max(np.abs(rot.T @ rot - np.eye(3))))
    if err > 1e-6 or np.linalg.det(rot) < 0.0 or not np.allclose(arr[3], [0, 0, 0, 1]):
        raise ValueError(
            f"{name} is not rigid: |R^T R - I| = {err:.2e}, det R = {np.linalg.det(rot):.6f}, "
            f"last row {arr[3].tolist()}"
        )


def residuals_and_jacobian(
    fld: Field, object_from_tool: np.ndarray, points_in_tool: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Field values ``r`` (N,) and the left-perturbation Jacobian ``J`` (N, 6)."""
    q = points_in_tool @ object_from_tool[:3, :3].T + object_from_tool[:3, 3]
    r, g = fld.value_and_grad(q)
    jac = np.empty((len(q), 6))
    jac[:, :3] = g
    # q x g, written out: np.cross is several times slower on (N, 3).
    jac[:, 3] = q[:, 1] * g[:, 2] - q[:, 2] * g[:, 1]
    jac[:, 4] = q[:, 2] * g[:, 0] - q[:, 0] * g[:, 2]
    jac[:, 5] = q[:, 0] * g[:, 1] - q[:, 1] * g[:, 0]
    return r, jac


def residuals(fld: Field, object_from_tool: np.ndarray, points_in_tool: np.ndarray) -> np.ndarray:
    """Field values (N,) of the tool-frame points under ``object_from_tool``."""
    q = points_in_tool @ object_from_tool[:3, :3].T + object_from_tool[:3, 3]
    return fld.value(q)


def scaled_information(jac: np.ndarray, length_m: float) -> np.ndarray:
    """``S J^T J S / N`` with rotations scaled to metres at lever arm ``length_m``.

    Per point and in one unit, so the eigenvalues compare with a fixed floor: a
    direction along which every point's field gradient moves by its full length has
    eigenvalue about 1.
    """
    n = max(len(jac), 1)
    scale = np.array([1.0, 1.0, 1.0, 1.0 / length_m, 1.0 / length_m, 1.0 / length_m])
    js = jac * scale
    info: np.ndarray = (js.T @ js) / n
    return info


def observability(
    info: np.ndarray, floor: float
) -> tuple[tuple[bool, ...], np.ndarray, np.ndarray]:
    """Observable axes and the eigen-split of a scaled information matrix.

    Returns:
        ``(observable per axis, observable eigenvectors (6, k), their eigenvalues (k,))``.
        An axis is unobservable when more than half of it lies in the span of the
        eigenvectors whose eigenvalue is under ``floor``.
    """
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    weak = w < floor
    share = np.sum(v[:, weak] ** 2, axis=1)
    flags = tuple(bool(s <= 0.5) for s in share)
    return flags, v[:, ~weak], w[~weak]


def characteristic_length(fld: Field) -> float:
    """Half the diagonal of the field's bounding box: the lever arm of a rotation."""
    lo, hi = fld.bounds_m()
    return max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
