"""What every pose solver shares: the problem, the result, observability, seeds, errors.

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

import functools
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
            lost to another seed's), ``suspect`` (see ``message``: the fit is worse
            than the noise allows, another distinct minimum fits about as well, too few
            directions are observable, or the solver did not converge), ``no_patch``
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

    @property
    def tool_from_object(self) -> np.ndarray:
        """The inverse of :attr:`object_from_tool` (what ``PoseEstimate`` carries)."""
        return se3.invert(self.object_from_tool)


def clean_points(points: np.ndarray, max_points: int | None = None, seed: int = 0) -> np.ndarray:
    """Finite rows of an (N, 3) cloud as float64, subsampled to ``max_points`` (fixed seed).

    Subsampling with a fixed generator keeps a repeated solve on the same patch
    deterministic.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if max_points is not None and len(pts) > max_points:
        idx = np.random.default_rng(seed).choice(len(pts), size=max_points, replace=False)
        pts = pts[np.sort(idx)]
    return pts


MIN_POINTS = 6  # six unknowns
MIN_SPREAD_M = 1e-5  # the smallest principal standard deviation a cloud must reach


def spread_problem(points: np.ndarray, min_spread_m: float = MIN_SPREAD_M) -> str:
    """Why finite (N, 3) points cannot fix a pose ("" if they can): too few, all at one
    point, on a line or on a plane (principal standard deviations under ``min_spread_m``)."""
    n = len(points)
    if n < MIN_POINTS:
        return f"{n} finite points, at least {MIN_POINTS} needed"
    centred = points - points.mean(axis=0)
    # Eigenvalues of the 3x3 scatter, largest first: far cheaper than an SVD of (N, 3).
    std = np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred / n)[::-1], 0.0))
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
    _, vecs = np.linalg.eigh(np.einsum("qki,qkj->qij", hood, hood))
    local = np.einsum("qki,qij->qkj", hood, vecs)  # coordinates in the principal frame
    u, v, w = local[..., 2], local[..., 1], local[..., 0]  # w along the least spread
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)
    gram = np.einsum("qki,qkj->qij", design, design) + 1e-18 * np.eye(6)
    coef = np.linalg.solve(gram, np.einsum("qki,qk->qi", design, w)[..., None])[..., 0]
    resid = w - np.einsum("qki,qi->qk", design, coef)
    var = np.sum(resid * resid, axis=1) / (k - 6)
    return float(np.sqrt(np.median(var)))


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
    return (js.T @ js) / n


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
    return float(max(0.5 * np.linalg.norm(hi - lo), 1e-3))


def axis_error_deg(
    tool_from_object_est: np.ndarray, tool_from_object_true: np.ndarray, *, flip_symmetric: bool
) -> float:
    """Angle between the estimated and true object z axes in the tool frame (degrees).

    With ``flip_symmetric`` the axis is a line (a plain cylinder: z and -z look alike).
    """
    a = tool_from_object_est[:3, 2]
    b = tool_from_object_true[:3, 2]
    ang = se3.angle_between(a, b)
    if flip_symmetric:
        ang = min(ang, np.pi - ang)
    return float(np.degrees(ang))


def offaxis_error_m(tool_from_object_est: np.ndarray, tool_from_object_true: np.ndarray) -> float:
    """Distance of the estimated origin from the true axis line (metres, tool frame)."""
    axis = tool_from_object_true[:3, 2]
    d = tool_from_object_est[:3, 3] - tool_from_object_true[:3, 3]
    return float(np.linalg.norm(d - (d @ axis) * axis))


def frame_from_axis(axis: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """A ``tool_from_object`` whose z is ``axis`` (normalized) at ``centre``; x arbitrary."""
    z = np.asarray(axis, dtype=np.float64)
    z = z / max(np.linalg.norm(z), 1e-300)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return se3.make_pose(np.stack([x, y, z], axis=1), centre)


def seed_poses(points_in_tool: np.ndarray, bubble: np.ndarray | None = None) -> list[np.ndarray]:
    """Starting ``tool_from_object`` poses for a cold start, most likely first.

    The first few come from the data: the object centre is put midway between the two
    bubbles' patch centroids, and the axis along each patch's principal direction (a
    cylinder touches a bubble along a line parallel to its axis), then the other
    in-plane direction. Then the cardinal poses: axis along tool x, y, z. Each axis is
    also tried flipped (top and bottom differ for bottles and glasses).
    """
    pts = np.asarray(points_in_tool, dtype=np.float64)
    if len(pts) == 0:
        return [np.eye(4)]
    groups = [pts]
    if bubble is not None and len(bubble) == len(pts):
        groups = [pts[bubble == k] for k in (0, 1) if np.any(bubble == k)]
    centroids = [g.mean(axis=0) for g in groups if len(g)]
    centre = np.mean(centroids, axis=0)
    axes: list[np.ndarray] = []
    for g in groups:
        if len(g) >= 3:
            centred = g - g.mean(axis=0)
            _, vecs = np.linalg.eigh(centred.T @ centred)  # ascending: principal last
            axes += [vecs[:, 2], vecs[:, 1]]
    axes += [np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])]
    unique: list[np.ndarray] = []
    for a in axes:
        a = a / max(np.linalg.norm(a), 1e-300)
        if all(abs(a @ u) < 0.985 for u in unique):  # 10 degrees apart at least
            unique.append(a)
    seeds = []
    for a in unique:
        seeds.append(frame_from_axis(a, centre))
        seeds.append(frame_from_axis(-a, centre))
    return seeds


@functools.cache
def symmetry_rotations(fld: Field) -> tuple[np.ndarray, ...]:
    """The turns that map the field onto itself among the 24 axis-permuting rotations
    (a box's 90- and 180-degree turns, a cylinder's flip; the identity first), found by
    checking the field on its own surface samples. Yaw of a body of revolution is
    continuous and handled by comparing axes instead (:func:`pose_difference`)."""
    pts = fld.sample_surface(400, np.random.default_rng(7))
    scale = characteristic_length(fld)
    out = []
    for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (2, 1, 0), (1, 0, 2)):
        for signs in np.ndindex(2, 2, 2):
            rot = np.zeros((3, 3))
            rot[np.arange(3), perm] = [1.0 if s == 0 else -1.0 for s in signs]
            if np.linalg.det(rot) < 0.0:
                continue
            if float(np.max(np.abs(fld.value(pts @ rot.T)))) < 1e-6 * scale:
                out.append(rot)
    out.sort(key=lambda r: -float(np.trace(r)))  # the identity first
    return tuple(out)


def pose_difference(
    fld: Field, a: np.ndarray, b: np.ndarray, observable: tuple[bool, ...] = (True,) * 6
) -> tuple[float, float]:
    """How far apart two ``object_from_tool`` estimates are, up to the object's symmetry:
    ``(angle_deg, offset_m)``.

    For a body of revolution the angle is between the axes (as lines when the flip is
    a symmetry) and the offset is that of ``b``'s origin from ``a``'s axis; otherwise
    the smallest rotation angle over the symmetry turns and the distance of the
    origins. Translations along directions ``observable`` marks ``False`` (in ``a``'s
    object frame) are not counted: the patch does not fix them.
    """
    ta, tb = se3.invert(a), se3.invert(b)
    turns = symmetry_rotations(fld)
    # b's origin from a's, in a's object frame, along the observable axes only.
    seen = np.asarray(observable[:3], dtype=np.float64)
    offset = float(np.linalg.norm(seen * (a[:3, :3] @ (tb[:3, 3] - ta[:3, 3]))))
    if not any(observable[3:]):  # a sphere's turns are all invisible
        return 0.0, offset
    if fld.revolves_about_z:
        flip = any(r[2, 2] < 0 for r in turns)
        return (
            axis_error_deg(tb, ta, flip_symmetric=flip),
            offaxis_error_m(tb, ta),
        )
    angle = min(
        float(np.degrees(se3.rotation_angle((ta[:3, :3] @ r).T @ tb[:3, :3]))) for r in turns
    )
    return angle, offset
