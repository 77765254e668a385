"""The judgement of an estimate: how sure it is, and whether a user may act on it.

Uncertainty (:func:`uncertainty`), from the fit at the estimate whatever solver found it:

- Curvature: the Gauss-Newton information ``J^T J`` of the residuals at the estimate,
  in the scaled twist coordinates of ``problem.scaled_information`` (rotations in metres
  at the object's lever arm). Its eigenvectors under ``floor`` per point are the
  directions the patch does not observe (yaw of a body of revolution, slide along a
  cylinder seen on its side, slide and turn within a box face seen on two faces); the
  covariance is zero along them and ``observable`` says so. Only the points where the
  field is smooth across the noise count here: a slide seen only through the few noisy
  points pushed past a rim is not observed (its Gaussian spread would not describe
  its error). A direction those points miss counts still when the whole cloud observes
  it through at least ``SPREAD`` of its points (a box's corner at 3 mm noise, where the
  noise crosses an edge almost everywhere but each face holds a third of the points).
  The spread's curvature is measured (:func:`curvature`): where points cross an edge
  or a corner the cost is flatter than ``J^T J`` says. Its finite differences are
  noisy along a weak direction, so each direction keeps a floor of ``J^T J``: for the
  stated spreads (the sandwich, the edges' and the faces' allowances)
  ``SPREAD_CURVATURE_FLOOR``, for the Newton steps that undo the rays' bias the higher
  ``CURVATURE_FLOOR`` (0.5; below it some steps went tens of degrees astray). A spread
  stated wider than the errors costs a ``suspect`` verdict; a correction too large, a
  wrong answer.
- Noise: the residuals themselves, point by point (the "sandwich" covariance
  ``H^-1 (sum r_i^2 a_i a_i^T) H^-1``, ``H`` the measured curvature, about
  ``sum a_i a_i^T``): noise along the
  camera rays leaves less in the residual where a ray meets the surface obliquely, and
  the sandwich follows that without a noise model. It is taken over every direction
  the whole cloud constrains (the solver moves along all of them, the points past an
  edge too) and then stated over the observed ones: their marginal, not their spread
  with the rest held at the truth.
- Edges: a point the noise carries across an edge or a corner (its gradient turns
  within ``EDGE_REACH`` residual RMS along it) may carry a coherent residual that the
  rays' bias below does not predict, ``EDGE_ERROR`` of the residual RMS at every such
  point, in one sense (a box's corner at 3 mm noise: the errors were two to three times
  the spread without it).
- Bias from the rays (``rays_in_tool``, from ``cloud.camera_rays``): each camera looks
  at its membrane obliquely (about 55 degrees from the plate's normal), so the depth
  noise moves a point along the surface as well as across it, and on a curved surface,
  an edge or a rim, the point's residual and its Jacobian row then change together.
  Their product does not average out: the fit's minimum sits off the truth by
  ``-H^-1 E[sum r_i J_i]`` (``bias.ray_bias``, averaged over the noise along each ray),
  about quadratic in the noise and the same for any number of points (a 30 mm cylinder
  at 3 mm noise: 0.1-0.5 mm and 0.3-0.6 degrees, up to nine times the statistical
  spread at 3000 points). The pose where the fit's gradient equals the predicted
  bias, along the observed directions with the others held where the solver left them
  (``bias.unbiased``: Newton steps on the data's gradient), is returned as
  ``correction`` (the estimator applies it), and what the prediction misses is added
  to the covariance: ``BIAS_ERROR`` of that move, and a share of each face's part of
  it on its own (at a box's corner the prediction was 10-35% off per component, not
  along the move), ``FACE_ERROR`` at the ray noise ``FACE_NOISE_M`` and in proportion
  to the ray noise (the misprediction grows with it). Without rays (no bubble labels) a cruder term stands in: a
  coherent bias of ``b = MODEL_ERROR * noise^2 / length`` per point, ``b^2 n H^-1``,
  with ``length`` the object's half diagonal; it does not know the rays' direction and
  is not calibrated.
- Calibration: the parts are kept (:class:`Terms`) and weighed by four shares
  (:func:`calibrated`): ``INFLATION`` (1: no factor on the statistical part),
  ``EDGE_ERROR`` (0.2), ``FACE_ERROR`` (0.25, at the ray noise ``FACE_NOISE_M``, 2.85
  mm, measured at a box's corner at 3 mm) and ``BIAS_ERROR`` (0.1), fitted by
  ``bench.pose_calib`` on clouds 600-699 of ``bench.pose_hard``'s coverage rows (the
  coverage rows score on 200-399): every set of a grid scored by the fewest wrong
  answers within the tolerance, then the fewest shapes with 5% or more of their right
  answers ``suspect``, then the cells' squared binomial z from 95% (z^2 32.0 over 28
  cells; the round before's 0.15, 0.25 and 0.4: 40.8; with the spread's curvature floor
  lowered to 0.3 afterwards, 34.1, not refitted: the grid's best there is one cloud's
  worth better and narrows the box corners at 10k points; docs/pose.md).
- Short of the minimum: ``step`` is the Gauss-Newton step from the estimate to the
  minimum of the fit, ``step_sigma`` its size in 95% regions; the estimator takes a
  solver that stopped short up to two such steps further before it judges.

The 95% region is the ellipsoid ``c^T C^-1 c <= chi2_k(0.95)`` over the ``k`` observable
directions. ``region95_deg`` and ``region95_m`` are its extent: the largest rotation and
the largest displacement of the object's origin it allows.

Comparisons (:func:`observed_difference`): two poses are compared along the observable
directions only: motion along unobservable ones is removed first (a yaw of a cylinder,
a slide along a face), then the rest is expressed in the observable coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry import se3
from geometry.fields import Field
from perception.pose.bias import BIAS_POINTS, unbiased
from perception.pose.problem import (
    DOF_NAMES,
    characteristic_length,
    observability,
    residuals_and_jacobian,
    scaled_information,
)

#: chi-square 95% quantiles for 0-6 degrees of freedom.
CHI2_95 = (0.0, 3.841, 5.991, 7.815, 9.488, 11.070, 12.592)
#: ``ok`` needs the answer within the tolerance with this probability
#: (``within_tolerance``; with 0.95, 3 of 1120 coverage rows' answers were wrong and ``ok``).
CONFIDENCE = 0.995
DRAWS = np.random.default_rng(0).standard_normal((4000, 6))
#: Fitted calibration (module docstring; refitted by ``bench.pose_calib``, scored by
#: ``bench.pose_hard``'s coverage rows).
INFLATION = 1.0
BIAS_ERROR = 0.1
#: The share by which the rays' bias from each face's points may be mispredicted, each
#: face on its own, at the ray noise ``FACE_NOISE_M`` (that of a box's corner at 3 mm
#: noise), in proportion to the ray noise (module docstring).
FACE_ERROR = 0.25
FACE_NOISE_M = 0.00285
#: The unpredicted coherent residual, as a share of the residual RMS, of each point that
#: is not smooth across the noise (past an edge or a corner; module docstring).
EDGE_ERROR = 0.2
#: The stand-in for the rays' bias when the rays are not known (module docstring).
MODEL_ERROR = 1.0
#: How far along its gradient (in residual RMS) the field may turn at a point for the
#: point to count as one the noise carries across an edge (``EDGE_ERROR``).
EDGE_REACH = 3.0
#: How far along its gradient (in residual RMS) the field must stay smooth at a point for
#: the point to count toward what the patch observes.
REACH = 6.0
#: The curvature is measured over this many standard deviations either way, and kept
#: at least this share of Gauss-Newton's along every direction (``Curvature.kept``) for
#: the Newton steps that undo the rays' bias, and at least the second for the stated
#: spread (module docstring; chosen on the fit set of ``bench.pose_calib`` and its box
#: corners at 3 mm with 10k points, docs/pose.md).
CURVATURE_STEP = 2.0
CURVATURE_FLOOR = 0.5
SPREAD_CURVATURE_FLOOR = 0.3
#: The least share of the points through which a direction the smooth points do not
#: observe must be observed to count (``_widely_observed``).
SPREAD = 0.1
#: The least share of the points through which the smooth points must observe a direction.
FEW = 0.01


@dataclass(frozen=True, kw_only=True)
class Terms:
    """The parts of an estimate's covariance before the fitted shares weigh them
    (:func:`calibrated`), in the coordinates of its ``k`` observed directions ``basis``
    (scaled twist coordinates; ``length_m`` the lever arm): ``sandwich`` (k, k), the
    statistical spread; ``edge`` (k,), the coherent residual past edges per unit of
    ``EDGE_ERROR``; ``stand_in`` (k, k), the bias without rays per unit of
    ``MODEL_ERROR`` squared (zeros with rays); ``shift`` (k,), the move that undoes the
    rays' bias, and ``faces`` (6, k), each face's share of it (with the spread's
    curvature), weighed at the ray noise
    ``face_scale`` times ``FACE_NOISE_M``; ``step`` (k,), the Gauss-Newton step to the
    minimum of the fit."""

    observable: tuple[bool, ...]
    basis: np.ndarray
    length_m: float
    sandwich: np.ndarray
    edge: np.ndarray
    stand_in: np.ndarray
    shift: np.ndarray
    faces: np.ndarray
    face_scale: float
    step: np.ndarray
    noise_mean_m: float


@dataclass(frozen=True, kw_only=True)
class Uncertainty:
    """How sure an estimate is (module docstring).

    Attributes:
        covariance: (6, 6) covariance of the left twist ``(tx, ty, tz, rx, ry, rz)``
            (metres, radians) in the object frame; zero along unobservable directions.
        observable: per twist axis: whether the patch observes it.
        basis: (6, k) the observable directions, in scaled twist coordinates.
        length_m: the lever arm of the scaled coordinates.
        inverse: (k, k) inverse covariance in ``basis`` coordinates.
        region95_deg: the largest rotation within the 95% region.
        region95_m: the largest displacement of the object's origin within it.
        step_sigma: the Gauss-Newton step from the estimate to the minimum of the fit,
            as a fraction of the 95% region's size along it (0 at the minimum; 1 at
            the region's edge): how far the solver stopped short.
        step: (6,) that step, as a left twist.
        correction: (6,) the left twist that moves the estimate onto the truth by the
            bias the rays predict (zeros without rays): ``exp(correction) X``.
        noise_mean_m: the mean residual the noise along the rays leaves at the right
            pose (0 without rays): the residuals' mean is biased only beyond it.
        terms: the covariance's parts before calibration (None when not computed here).
    """

    covariance: np.ndarray
    observable: tuple[bool, ...]
    basis: np.ndarray
    length_m: float
    inverse: np.ndarray
    region95_deg: float
    region95_m: float
    step_sigma: float
    step: np.ndarray = field(default_factory=lambda: np.zeros(6))
    correction: np.ndarray = field(default_factory=lambda: np.zeros(6))
    noise_mean_m: float = 0.0
    terms: Terms | None = None

    @property
    def scale(self) -> np.ndarray:
        """Scaled twist coordinates to twist coordinates."""
        return np.array([1.0] * 3 + [1.0 / self.length_m] * 3)

    @property
    def unobservable(self) -> list[str]:
        """Names of the twist axes the patch does not observe."""
        return [name for name, seen in zip(DOF_NAMES, self.observable, strict=True) if not seen]


def _nothing(length_m: float) -> Uncertainty:
    return Uncertainty(
        covariance=np.zeros((6, 6)),
        observable=(False,) * 6,
        basis=np.zeros((6, 0)),
        length_m=length_m,
        inverse=np.zeros((0, 0)),
        region95_deg=0.0,
        region95_m=0.0,
        step_sigma=0.0,
    )


def from_covariance(covariance: np.ndarray, length_m: float) -> Uncertainty:
    """The :class:`Uncertainty` a (6, 6) twist covariance describes (as an estimate
    carries it), for comparing poses with it; ``step_sigma`` is not known (0)."""
    scale = np.array([1.0] * 3 + [1.0 / length_m] * 3)
    scaled = np.asarray(covariance, dtype=np.float64) / np.outer(scale, scale)
    vals, vecs = np.linalg.eigh(0.5 * (scaled + scaled.T))
    keep = vals > 1e-12 * max(float(vals[-1]), 1e-300)
    basis = vecs[:, keep]
    k = basis.shape[1]
    if k == 0:
        return _nothing(length_m)
    inverse = np.diag(1.0 / vals[keep])
    share = np.sum(basis**2, axis=1)
    q95 = CHI2_95[k]
    return Uncertainty(
        covariance=np.asarray(covariance, dtype=np.float64),
        observable=tuple(bool(s > 0.5) for s in share),
        basis=basis,
        length_m=length_m,
        inverse=inverse,
        region95_deg=float(
            np.degrees(np.sqrt(q95 * max(np.linalg.eigvalsh(covariance[3:, 3:])[-1], 0)))
        ),
        region95_m=float(np.sqrt(q95 * max(np.linalg.eigvalsh(covariance[:3, :3])[-1], 0.0))),
        step_sigma=0.0,
    )


@dataclass(frozen=True)
class Curvature:
    """A measured curvature (:func:`curvature`) in Gauss-Newton's whitened coordinates:
    ``axes`` (m, m) the eigenvectors of ``J^T J``, ``root`` the square roots of its
    eigenvalues, ``white`` the measured curvature divided by them both ways."""

    axes: np.ndarray
    root: np.ndarray
    white: np.ndarray

    def kept(self, floor: float) -> np.ndarray:
        """The curvature with each whitened direction kept between ``floor`` and all of
        ``J^T J`` (a weak direction's difference rests on the few points that cross an
        edge within the step, and is noisy), in the coordinates :func:`curvature` was
        given."""
        wvals, wvecs = np.linalg.eigh(self.white)
        white = (wvecs * np.clip(wvals, floor, 1.0)) @ wvecs.T
        kept: np.ndarray = self.axes @ (white * np.outer(self.root, self.root)) @ self.axes.T
        return kept


def curvature(
    fld: Field,
    object_from_tool: np.ndarray,
    points_in_tool: np.ndarray,
    directions: np.ndarray,
    gauss_newton: np.ndarray,
    r: np.ndarray,
) -> Curvature:
    """The curvature of the half cost along ``directions`` (6, m: left twists), measured:
    the change of its gradient over ``CURVATURE_STEP`` standard deviations either way
    (central differences, at most ``BIAS_POINTS`` points scaled to all), along the
    eigenvectors of Gauss-Newton's ``J^T J`` (``gauss_newton``, m x m) and returned in the
    coordinates of ``directions``: the measure does not depend on how those are chosen
    (a secant is not a quadratic form: measured along the axes of an SVD, which turn
    freely where its singular values are equal, two LM stops 1e-3 degree apart at one
    minimum of a box's corner stated 0.71 and 1.15 degrees along its weak rotation).
    Where a point crosses an edge the cost is flatter than ``J^T J`` says (a box's corner
    at 3 mm: by a third, along its weak rotation by up to four fifths); the
    :class:`Curvature` keeps each direction between a floor and all of it."""
    stride = -(-len(r) // BIAS_POINTS)
    pts = points_in_tool[::stride]
    weight = len(points_in_tool) / len(pts)
    vals, axes = np.linalg.eigh(0.5 * (gauss_newton + gauss_newton.T))
    along = directions @ axes
    sigma = np.sqrt(float(r @ r) / len(r) / np.maximum(vals, 1e-300))
    measured = np.empty_like(gauss_newton)
    for j in range(along.shape[1]):
        grads = []
        for sign in (1.0, -1.0):
            pose = se3.exp_se3(sign * CURVATURE_STEP * sigma[j] * along[:, j]) @ object_from_tool
            value, rows = residuals_and_jacobian(fld, pose, pts)
            grads.append(weight * ((rows @ along).T @ value))
        measured[:, j] = (grads[0] - grads[1]) / (2.0 * CURVATURE_STEP * sigma[j])
    root = np.sqrt(vals)
    return Curvature(axes, root, 0.5 * (measured + measured.T) / np.outer(root, root))


def _spread(js: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Through how many of the points (rows of ``js``, scaled Jacobian rows) each of
    ``directions`` (6, m) is observed: the effective count ``(sum c_i)^2 / sum c_i^2``
    of the points' shares ``c_i`` of its information."""
    shares = (js @ directions) ** 2
    count: np.ndarray = shares.sum(axis=0) ** 2 / np.maximum((shares**2).sum(axis=0), 1e-300)
    return count


def _widely_observed(
    basis: np.ndarray, info: np.ndarray, js: np.ndarray, floor: float
) -> np.ndarray:
    """``basis`` (6, k), the directions the smooth points observe, with the directions
    orthogonal to it that the whole cloud observes (``info``, from every row of ``js``)
    through at least ``SPREAD`` of its points (``_spread``): a box's corner at 3 mm sees
    each face through a third of its points; a slide seen past a rim, under 5%."""
    rest = np.linalg.svd(basis, full_matrices=True)[0][:, basis.shape[1] :]
    if rest.shape[1] == 0:
        return basis
    vals, vecs = np.linalg.eigh(rest.T @ info @ rest)
    wide = (vals >= floor) & (_spread(js, rest @ vecs) >= SPREAD * len(js))
    return np.hstack([basis, rest @ vecs[:, wide]])


def _smooth(fld: Field, q: np.ndarray, grad: np.ndarray, reach: float) -> np.ndarray:
    """Whether the field's gradient at each point ``q`` (object frame; ``grad`` there)
    stays the same ``reach`` either way along it."""
    smooth = np.ones(len(q), dtype=bool)
    for sign in (-1.0, 1.0):
        _, moved = fld.value_and_grad(q + sign * reach * grad)
        smooth &= np.sum(moved * grad, axis=1) > 0.99
    return smooth


def uncertainty(
    fld: Field,
    object_from_tool: np.ndarray,
    points_in_tool: np.ndarray,
    *,
    rays_in_tool: np.ndarray | None = None,
    floor: float = 1e-4,
) -> Uncertainty:
    """The uncertainty of ``object_from_tool`` on finite (N, 3) points (module docstring);
    ``rays_in_tool`` (N, 3): each point's camera ray (``cloud.camera_rays``), for the
    bias that noise along them leaves. Its :class:`Terms` weighed by the fitted shares
    (:func:`calibrated`)."""
    length = characteristic_length(fld)
    r, jac = residuals_and_jacobian(fld, object_from_tool, points_in_tool)
    n = len(r)
    # Which directions the patch observes is decided by the points where the field is
    # smooth across the noise; a point that noise pushed past a rim or an edge (its
    # gradient turns within REACH residual RMS along itself) would make a slide "observed".
    q = points_in_tool @ object_from_tool[:3, :3].T + object_from_tool[:3, 3]
    rms = float(np.sqrt(r @ r / max(n, 1)))
    smooth = _smooth(fld, q, jac[:, :3], REACH * rms)
    info = scaled_information(jac[smooth], length) * (int(smooth.sum()) / max(n, 1))
    _, basis, _ = observability(info, floor)
    # The floor is per point (a third of one point in 3000): a direction seen through
    # under FEW of the points rests on an outlier thrown past a rim.
    scale = np.array([1.0] * 3 + [1.0 / length] * 3)
    js = jac * scale
    basis = basis[:, _spread(js[smooth], basis) >= FEW * n]
    basis = _widely_observed(basis, scaled_information(jac, length), js, floor)
    flags = tuple(bool(s > 0.5) for s in np.sum(basis**2, axis=1))
    k = basis.shape[1]
    if k == 0 or n <= k:
        return _nothing(length)
    # The solver moves along every direction the whole cloud constrains (the points
    # past an edge or a rim too), so the error along the observed directions is its
    # marginal over all of those, not the spread with the others held at the truth.
    _, seen_by_all, _ = observability(scaled_information(jac, length), floor)
    u, spans, _ = np.linalg.svd(np.hstack([basis, seen_by_all]), full_matrices=False)
    joint = u[:, spans > 1e-6]  # both sets orthonormal: their union's span
    if n <= joint.shape[1]:
        return _nothing(length)
    a = js @ joint
    measured = curvature(fld, object_from_tool, points_in_tool, joint * scale[:, None], a.T @ a, r)
    h_steps = measured.kept(CURVATURE_FLOOR)
    h_spread = measured.kept(SPREAD_CURVATURE_FLOOR)
    h_inv = np.linalg.inv(h_spread)
    onto = basis.T @ joint  # joint coordinates -> observed coordinates
    meat = (a * (r * r)[:, None]).T @ a
    sandwich = onto @ (h_inv @ meat @ h_inv) @ onto.T * n / (n - joint.shape[1])
    # Past an edge or a corner the noise leaves a residual whose mean the rays' bias does
    # not fully predict: each point that is not smooth across the noise may carry a
    # coherent share of the residual RMS, all in one sense.
    crossed = ~_smooth(fld, q, jac[:, :3], EDGE_REACH * rms)
    edge = onto @ h_inv @ a[crossed].sum(axis=0) * rms
    twist = basis * scale[:, None]  # basis coordinates -> twist
    if rays_in_tool is None:
        stand_in = (float(r @ r) / n / length) ** 2 * n * (onto @ h_inv @ onto.T)
        shift, faces, noise_mean, face_scale = np.zeros(k), np.zeros((6, k)), 0.0, 0.0
    else:
        # The fit's minimum sits off the truth where the gradient equals its bias; the
        # pose where it does is solved for along the observed directions, the others
        # held (``bias.unbiased``); what the prediction misses is taken as a share of it.
        stand_in = np.zeros((k, k))
        shift, noise_mean, gradients, ray_noise = unbiased(
            fld,
            object_from_tool,
            points_in_tool,
            rays_in_tool,
            r,
            jac,
            twist,
            np.linalg.inv(onto @ h_steps @ onto.T),
            sandwich,
        )
        faces = np.linalg.solve(onto @ h_spread @ onto.T, gradients.T).T
        face_scale = ray_noise / FACE_NOISE_M
    a = js @ basis
    terms = Terms(
        observable=flags,
        basis=basis,
        length_m=length,
        sandwich=sandwich,
        edge=edge,
        stand_in=stand_in,
        shift=shift,
        faces=faces,
        face_scale=face_scale,
        step=-np.linalg.solve(a.T @ a, a.T @ r),
        noise_mean_m=noise_mean,
    )
    return calibrated(terms)


def calibrated(
    terms: Terms,
    *,
    inflation: float = INFLATION,
    edge_error: float = EDGE_ERROR,
    face_error: float = FACE_ERROR,
    bias_error: float = BIAS_ERROR,
    model_error: float = MODEL_ERROR,
) -> Uncertainty:
    """The :class:`Uncertainty` the ``terms`` state, weighed by the fitted shares (module
    docstring; ``bench.pose_calib`` refits them)."""
    k = terms.basis.shape[1]
    face = face_error * terms.face_scale
    cov = (
        inflation**2 * terms.sandwich
        + edge_error**2 * np.outer(terms.edge, terms.edge)
        + model_error**2 * terms.stand_in
        + bias_error**2 * np.outer(terms.shift, terms.shift)
        + face**2 * (terms.faces.T @ terms.faces)
    )
    cov = 0.5 * (cov + cov.T)
    inverse = np.linalg.inv(cov)
    q95 = CHI2_95[k]
    twist = terms.basis * np.array([1.0] * 3 + [1.0 / terms.length_m] * 3)[:, None]
    cov6 = twist @ cov @ twist.T
    return Uncertainty(
        covariance=cov6,
        observable=terms.observable,
        basis=terms.basis,
        length_m=terms.length_m,
        inverse=inverse,
        region95_deg=float(np.degrees(np.sqrt(q95 * max(np.linalg.eigvalsh(cov6[3:, 3:])[-1], 0)))),
        region95_m=float(np.sqrt(q95 * max(np.linalg.eigvalsh(cov6[:3, :3])[-1], 0.0))),
        step_sigma=float(np.sqrt(terms.step @ inverse @ terms.step / q95)),
        step=twist @ terms.step,
        correction=twist @ terms.shift,
        noise_mean_m=terms.noise_mean_m,
        terms=terms,
    )


def within_tolerance(unc: Uncertainty, tolerance_deg: float, tolerance_m: float) -> float:
    """The probability, under the Gaussian ``unc`` states, that the truth lies within
    ``tolerance_deg`` of rotation and ``tolerance_m`` of displacement of the object's
    origin from the estimate along the observed directions (1 with none observed): what
    ``ok`` asks, at least ``CONFIDENCE``. Over the fixed draws ``DRAWS`` (deterministic;
    about +-0.1% at 99.5%). The 95% region's extent bounds the same from above, over all
    the observed directions at once (a box's corner at 2 mm: regions of 1.9-3.2 degrees
    put the truth within 2 degrees with probability 0.975-1)."""
    vals, vecs = np.linalg.eigh(0.5 * (unc.covariance + unc.covariance.T))
    twist = (DRAWS * np.sqrt(np.maximum(vals, 0.0))) @ vecs.T
    rotation = np.degrees(np.linalg.norm(twist[:, 3:], axis=1))
    displacement = np.linalg.norm(twist[:, :3], axis=1)
    return float(np.mean((rotation <= tolerance_deg) & (displacement <= tolerance_m)))


def observed_difference(
    unc: Uncertainty, object_from_tool: np.ndarray, other: np.ndarray
) -> np.ndarray:
    """``other`` relative to the estimate ``object_from_tool`` in the observable
    coordinates of ``unc``, after motion along the unobservable directions is removed."""
    return difference_along(unc.basis, unc.scale, object_from_tool, other)


def difference_along(
    basis: np.ndarray, scale: np.ndarray, object_from_tool: np.ndarray, other: np.ndarray
) -> np.ndarray:
    """``other`` relative to ``object_from_tool`` in the coordinates of ``basis`` (6, k),
    orthonormal directions in scaled twist coordinates (``scale``: scaled to twist),
    after motion along the directions orthogonal to them is removed."""
    null = np.linalg.svd(basis, full_matrices=True)[0][:, basis.shape[1] :]
    rel = other @ se3.invert(object_from_tool)
    for _ in range(20):
        along = null @ (null.T @ (se3.log_se3(rel) / scale))
        if float(np.linalg.norm(along)) < 1e-12:
            break
        rel = se3.exp_se3(-along * scale) @ rel
    coords: np.ndarray = basis.T @ (se3.log_se3(rel) / scale)
    return coords


def extent(
    unc: Uncertainty, coords: np.ndarray, *, ignore: tuple[int, ...] = ()
) -> tuple[float, float]:
    """The rotation (degrees) and origin displacement (metres) of a difference given in
    observable coordinates, leaving out the twist axes ``ignore``."""
    twist = (unc.basis @ coords) * unc.scale
    twist[list(ignore)] = 0.0
    return float(np.degrees(np.linalg.norm(twist[3:]))), float(np.linalg.norm(twist[:3]))


def within_region(unc: Uncertainty, coords: np.ndarray) -> float:
    """``c^T C^-1 c / chi2_k(0.95)``: at most 1 inside the 95% region."""
    k = len(coords)
    if k == 0:
        return 0.0
    return float(coords @ unc.inverse @ coords / CHI2_95[k])


def alternatives(
    unc: Uncertainty,
    object_from_tool: np.ndarray,
    others: list[np.ndarray],
    *,
    turns: list[tuple[np.ndarray, str]],
    tolerance_deg: float,
    tolerance_m: float,
) -> tuple[list[str], list[str]]:
    """Other minima that fit about as well as the answer, sorted: ``(those that agree
    with it on every observable direction within the tolerance, those that do not)``,
    described. Each is compared up to ``turns`` (the object's symmetry turns, and
    ``"end over end"`` for a body of revolution whose ends the patch may not see: then
    the axis and the position across it must agree, not the position along it)."""
    alike: list[str] = []
    differ: list[str] = []
    for other in others:
        angle, offset, how = np.inf, np.inf, ""
        for turn, label in turns:
            coords = observed_difference(unc, object_from_tool, se3.make_pose(turn) @ other)
            a, o = extent(unc, coords, ignore=(2,) if label else ())
            if max(a / tolerance_deg, o / tolerance_m) < max(
                angle / tolerance_deg, offset / tolerance_m
            ):
                angle, offset, how = a, o, label
        if angle <= tolerance_deg and offset <= tolerance_m:
            unseen = ", ".join(unc.unobservable) or "none"
            alike.append(
                "another minimum fits as well and differs only where the patch cannot see "
                f"({how or 'unobservable directions'}: {unseen})"
            )
        else:
            differ.append(
                f"another minimum {angle:.1f} deg / {1e3 * offset:.1f} mm away along "
                "observable directions fits as well"
            )
    return alike, differ
