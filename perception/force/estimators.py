"""Contact wrench from one bubble's features: a physics model and a ridge regressor.

Both give the force the object exerts on a bubble's membrane and its torque about the
tool frame's origin, tool frame, N and N m, with a one-sigma uncertainty per component
(the calibration's residual spread), and what physics leaves open is calibrated per rig
(:func:`calibrate`, docs/force.md):

``physics``
    * normal: the pressurised membrane presses with its gauge pressure over the patch,
      ``N = gain * p * A`` (``A`` projected on the plate), along the plate's outward
      normal (the object pushes the membrane towards the plate);
    * tangential, per tool axis ``j`` (y, z): the latex shears with a stiffness,
      ``F_j = k_j (A s_j) - c_j V``, where ``s`` is the dots' mean shift over the patch
      and ``V`` the displaced volume (``c`` absorbs the dots' apparent shift from the
      indentation alone, seen through an angled camera);
    * torque: the force applied at the patch's centroid, plus a torsional stiffness
      about the plate's normal, ``k_t A theta``.
    ``gain``, ``k``, ``c`` and ``k_t`` are least-squares fits against a rig's truth.

``ridge``
    A linear map from a fixed set of nonlinear features (products of pressure, area,
    volume, shifts, torsion and the centroid, :func:`feature_vector`) to the six wrench
    components, per bubble side, fitted by ridge regression on standardised features,
    its strength the one that reads grasps left out of the fit best (:func:`ridge_strength`).

Anything the features cannot see the estimators cannot either: a force along a
direction the dots do not move in (a patch too small to track) reads as zero; the
normal force of a patch under the contact threshold is missed.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from perception.force.features import ContactFeatures, shift_per_pressure

METHODS = ("physics", "ridge")
SIDES = ("left", "right")
MIN_SPREAD_ONSETS = 3  # fewer edge onsets than this say nothing of their spread
# The ridge's strengths tried (``lambda = strength n``, on standardised features), the
# first where fewer than ``MIN_RIDGE_GRASPS`` grasps leave none out to score it.
RIDGE_STRENGTHS = (1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0)
MIN_RIDGE_GRASPS = 3


@dataclass(frozen=True)
class BubbleWrench:
    """One bubble's estimated wrench (on the membrane from the object), tool frame."""

    force_n: np.ndarray
    torque_nm: np.ndarray
    force_sigma_n: np.ndarray
    torque_sigma_nm: np.ndarray

    @classmethod
    def zero(cls) -> BubbleWrench:
        return cls(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))


@dataclass(frozen=True, kw_only=True)
class PhysicsCalibration:
    """The physics model's per-rig constants (see the module docstring)."""

    gain: float = 1.0
    unseen_gain: float = 0.0
    stiffness_n_per_m3: tuple[float, float] = (4.5e5, 4.5e5)
    indent_bias_n_per_m3: tuple[float, float] = (0.0, 0.0)
    torsion_n_per_m_rad: float = 0.0
    force_sigma_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_sigma_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class RidgeCalibration:
    """Per side: feature means and scales, weights ``(features + 1, 6)``, sigmas (6,)."""

    mean: dict[str, list[float]] = field(default_factory=dict)
    scale: dict[str, list[float]] = field(default_factory=dict)
    weights: dict[str, list[list[float]]] = field(default_factory=dict)
    sigma: dict[str, list[float]] = field(default_factory=dict)
    ridge: float = 1e-3


@dataclass(frozen=True, kw_only=True)
class Calibration:
    """A rig's force calibration: both methods' constants, the friction coefficient
    (``friction``: tangential over normal force when the whole patch slips, fitted from
    slipping frames when there are any) and the slip detector's limits: the core's
    tangential shift per pascal of gauge pressure at which the patch's edge
    (``slip_edge_m_per_pa``), then the whole patch (``slip_patch_m_per_pa``), began to
    slip (medians over ``slip_onsets`` onsets of each; the defaults, ``world.sim``'s,
    where there were none), and how far the edge's onsets spread about their median
    (``slip_edge_spread``: standard deviation over median; 0 where fewer than
    ``MIN_SPREAD_ONSETS`` onsets measured it), which says how well the edge's limit is
    known: the slip detector uses it as a cue only where it is known well
    (``perception.force.slip``)."""

    rig: str = "uncalibrated"
    source: str = ""
    physics: PhysicsCalibration = field(default_factory=PhysicsCalibration)
    ridge: RidgeCalibration = field(default_factory=RidgeCalibration)
    friction: float = 0.8
    slip_edge_m_per_pa: float = 0.7e-6
    slip_patch_m_per_pa: float = 0.95e-6
    slip_onsets: tuple[int, int] = (0, 0)
    slip_edge_spread: float = 0.0
    samples: int = 0

    def __post_init__(self) -> None:
        if not (self.slip_edge_m_per_pa > 0 and self.slip_patch_m_per_pa > 0):
            raise ValueError(
                "`slip_edge_m_per_pa` and `slip_patch_m_per_pa` must be > 0, got"
                f" {self.slip_edge_m_per_pa!r}, {self.slip_patch_m_per_pa!r}"
            )
        if not 0.0 <= self.slip_edge_spread < float("inf"):
            raise ValueError(f"`slip_edge_spread` must be >= 0, got {self.slip_edge_spread!r}")

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1, sort_keys=True)

    @classmethod
    def from_dict(cls, data: Any, where: str = "<calibration>") -> Calibration:
        """Build from parsed JSON; errors name ``where`` and the field."""
        if not isinstance(data, dict):
            raise ValueError(f"{where}: a calibration must be a JSON object")
        try:
            physics_fields: dict[str, Any] = {
                k: tuple(v) if isinstance(v, list) else v
                for k, v in data.get("physics", {}).items()
            }
            physics = PhysicsCalibration(**physics_fields)
            ridge = RidgeCalibration(**data.get("ridge", {}))
            rest = {k: v for k, v in data.items() if k not in ("physics", "ridge")}
            if isinstance(rest.get("slip_onsets"), list):
                rest["slip_onsets"] = tuple(rest["slip_onsets"])
            return cls(physics=physics, ridge=ridge, **rest)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where}: {err}") from err

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file (JSON)."""
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise ValueError(f"{p}: cannot read the force calibration: {err}") from err
        return cls.from_dict(data, str(p))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_json() + "\n")


# -- physics ------------------------------------------------------------------------------


def unseen_m2(f: ContactFeatures) -> float:
    """The regressor of the patch the camera does not see: the pressure's rise (the gas
    law's measure of all the displaced volume) per seen mean indentation, ``dp A / V``."""
    if f.volume_m3 <= 1e-9:
        return 0.0
    return f.pressure_rise_pa * f.area_m2 / f.volume_m3 * 1e-6


def physics_wrench(f: ContactFeatures, cal: PhysicsCalibration) -> BubbleWrench:
    """The physics model's wrench for one bubble (zero out of contact)."""
    if not f.in_contact:
        return BubbleWrench.zero()
    force = (
        -f.pressure_pa * (cal.gain * f.area_m2 + cal.unseen_gain * unseen_m2(f)) * f.normal_in_tool
    )
    k, c = cal.stiffness_n_per_m3, cal.indent_bias_n_per_m3
    for j in (0, 1):
        force[1 + j] += k[j] * f.area_m2 * f.shift_m[j] - c[j] * f.volume_m3
    torque = np.cross(f.centroid_in_tool, force)
    torque[0] += cal.torsion_n_per_m_rad * f.area_m2 * f.torsion_rad
    return BubbleWrench(
        force, torque, np.asarray(cal.force_sigma_n, float), np.asarray(cal.torque_sigma_nm, float)
    )


# -- ridge --------------------------------------------------------------------------------


def feature_vector(f: ContactFeatures) -> np.ndarray:
    """The regressor's inputs for one bubble (zeros out of contact)."""
    if not f.in_contact:
        return np.zeros(FEATURES)
    p, a, v = f.pressure_pa / 1000.0, f.area_m2 * 1e4, f.volume_m3 * 1e6
    dp, u = f.pressure_rise_pa / 1000.0, unseen_m2(f) * 1e4
    s, core, edge = f.shift_m * 1e3, f.core_shift_m * 1e3, f.edge_shift_m * 1e3
    c = f.centroid_in_tool * 1e3
    pa = p * a
    return np.array(
        [
            p, a, v, pa, p * v, a * a,
            a * s[0], a * s[1], v * s[0], v * s[1], pa * s[0], pa * s[1],
            s[0], s[1], core[0], core[1], edge[0], edge[1],
            f.torsion_rad, a * f.torsion_rad,
            c[0], c[1], c[2],
            c[1] * pa, c[2] * pa, c[0] * a * s[0], c[0] * a * s[1], c[1] * a * s[1],
            c[2] * a * s[0], c[1] * v, c[2] * v,
            dp, p * u, u, dp * a,
        ]
    )  # fmt: skip


FEATURES = 35


def ridge_wrench(f: ContactFeatures, side: str, cal: RidgeCalibration) -> BubbleWrench:
    """The regressor's wrench for one bubble (zero out of contact or uncalibrated)."""
    if not f.in_contact or side not in cal.weights:
        return BubbleWrench.zero()
    x = (feature_vector(f) - np.asarray(cal.mean[side])) / np.asarray(cal.scale[side])
    y = np.append(x, 1.0) @ np.asarray(cal.weights[side])
    sigma = np.asarray(cal.sigma[side])
    return BubbleWrench(y[:3], y[3:], sigma[:3], sigma[3:])


def estimate(f: ContactFeatures, side: str, cal: Calibration, method: str) -> BubbleWrench:
    """One bubble's wrench by ``method`` (``physics`` or ``ridge``)."""
    if method == "physics":
        return physics_wrench(f, cal.physics)
    if method == "ridge":
        return ridge_wrench(f, side, cal.ridge)
    raise ValueError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")


# -- calibration --------------------------------------------------------------------------


@dataclass(frozen=True)
class Sample:
    """One bubble at one frame: its features and its true wrench (tool frame)."""

    side: str
    features: ContactFeatures
    force_n: np.ndarray
    torque_nm: np.ndarray
    slipping: float = 0.0  # the share of the patch's area slipping (1: the whole patch)
    grasp: int = 0  # which calibration grasp it was recorded in (the ridge's folds)


def _lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    solution: np.ndarray = np.linalg.lstsq(a, b, rcond=None)[0]
    return solution


def calibrate_physics(samples: list[Sample]) -> PhysicsCalibration:
    """Least-squares fits of the physics model's constants (samples in contact, tracked)."""
    used = [s for s in samples if s.features.in_contact and s.features.tracked]
    if len(used) < 4:
        raise ValueError(f"calibration needs at least 4 tracked contact samples, got {len(used)}")
    a = np.array(
        [
            [
                s.features.pressure_pa * s.features.area_m2,
                s.features.pressure_pa * unseen_m2(s.features),
            ]
            for s in used
        ]
    )
    normal = np.array([-(s.force_n @ s.features.normal_in_tool) for s in used])
    gain, unseen = (float(v) for v in _lstsq(a, normal))
    stiffness, bias = [], []
    for j in (0, 1):
        a = np.array(
            [[s.features.area_m2 * s.features.shift_m[j], -s.features.volume_m3] for s in used]
        )
        k, c = _lstsq(a, np.array([s.force_n[1 + j] for s in used]))
        stiffness.append(float(k))
        bias.append(float(c))
    base = PhysicsCalibration(
        gain=gain,
        unseen_gain=unseen,
        stiffness_n_per_m3=(stiffness[0], stiffness[1]),
        indent_bias_n_per_m3=(bias[0], bias[1]),
    )
    # Torsion: what the centroid's moment leaves of the torque about x.
    rest = np.array([s.torque_nm[0] - physics_wrench(s.features, base).torque_nm[0] for s in used])
    twist = np.array([s.features.area_m2 * s.features.torsion_rad for s in used])
    kt = float(twist @ rest / max(twist @ twist, 1e-18))
    base = PhysicsCalibration(**{**asdict(base), "torsion_n_per_m_rad": kt})
    errors = [(physics_wrench(s.features, base), s) for s in used]
    fs = np.sqrt(np.mean([(w.force_n - s.force_n) ** 2 for w, s in errors], axis=0))
    ts = np.sqrt(np.mean([(w.torque_nm - s.torque_nm) ** 2 for w, s in errors], axis=0))
    return PhysicsCalibration(
        **{
            **asdict(base),
            "force_sigma_n": tuple(map(float, fs)),
            "torque_sigma_nm": tuple(map(float, ts)),
        }
    )


def _fit_ridge(samples: list[Sample], ridge: float) -> RidgeCalibration:
    """Ridge fits per side of the wrench on :func:`feature_vector` (contact samples),
    ``lambda = ridge n`` on standardised features."""
    out: dict[str, Any] = {"mean": {}, "scale": {}, "weights": {}, "sigma": {}}
    for side in SIDES:
        used = [s for s in samples if s.side == side and s.features.in_contact]
        if len(used) < FEATURES:
            continue
        x = np.array([feature_vector(s.features) for s in used])
        y = np.array([np.concatenate([s.force_n, s.torque_nm]) for s in used])
        mean, scale = x.mean(axis=0), x.std(axis=0)
        scale[scale < 1e-9] = 1.0
        z = np.hstack([(x - mean) / scale, np.ones((len(x), 1))])
        reg = ridge * len(x) * np.eye(z.shape[1])
        reg[-1, -1] = 0.0  # the intercept is not shrunk
        w = np.linalg.solve(z.T @ z + reg, z.T @ y)
        sigma = np.sqrt(np.mean((z @ w - y) ** 2, axis=0))
        out["mean"][side], out["scale"][side] = mean.tolist(), scale.tolist()
        out["weights"][side], out["sigma"][side] = w.tolist(), sigma.tolist()
    return RidgeCalibration(**out, ridge=ridge)


def ridge_strength(samples: list[Sample]) -> float:
    """The ridge's strength that reads the force best on grasps it was not fitted on:
    of :data:`RIDGE_STRENGTHS`, the least median force error (N) over every grasp's
    contact samples, each predicted by the fit on the other grasps (``Sample.grasp``);
    the first with fewer than :data:`MIN_RIDGE_GRASPS` grasps.

    Its 35 features are products of a few measurements, nearly collinear over a few
    grasps: weakly shrunk, the fit follows what tells those grasps apart and reads
    another grasp's force far off (docs/force.md, "Two estimators")."""
    grasps = sorted({s.grasp for s in samples})
    if len(grasps) < MIN_RIDGE_GRASPS:
        return RIDGE_STRENGTHS[0]

    def held_out_error(ridge: float) -> float:
        errors = []
        for g in grasps:
            fit = _fit_ridge([s for s in samples if s.grasp != g], ridge)
            errors += [
                float(np.linalg.norm(ridge_wrench(s.features, s.side, fit).force_n - s.force_n))
                for s in samples
                if s.grasp == g and s.features.in_contact
            ]
        return float(np.median(errors)) if errors else float("inf")

    return min(RIDGE_STRENGTHS, key=held_out_error)


def calibrate_ridge(samples: list[Sample], ridge: float | None = None) -> RidgeCalibration:
    """Ridge fits per side of the wrench on :func:`feature_vector` (contact samples), with
    the strength ``ridge`` (default: :func:`ridge_strength`, chosen over the grasps)."""
    return _fit_ridge(samples, ridge_strength(samples) if ridge is None else ridge)


def calibrate_friction(samples: list[Sample], default: float = 0.8) -> float:
    """Tangential over normal force where the whole patch slipped (median), else ``default``."""
    ratios = [
        float(np.hypot(*s.force_n[1:]) / abs(s.force_n @ s.features.normal_in_tool))
        for s in samples
        if s.slipping >= 1.0
        and s.features.in_contact
        and abs(s.force_n @ s.features.normal_in_tool) > 0.2
    ]
    return float(np.median(ratios)) if ratios else default


def calibrate_slip(samples: list[Sample]) -> dict[str, Any]:
    """The slip detector's limits: the median core shift per pascal at the frames the
    truth's slip began, at the edge (some of the patch slips after none did) and over
    the whole patch (all of it after not all), and the edge's onsets' spread (standard
    deviation over median, from ``MIN_SPREAD_ONSETS`` onsets); ``samples`` in time
    order per side (as :func:`bench.force_data.samples` lists a grasp's frames).
    Calibration's defaults for a limit no onset measured."""
    last: dict[str, float] = {}
    onsets: dict[str, list[float]] = {"edge": [], "patch": []}
    for s in samples:
        before = last.get(s.side)
        last[s.side] = s.slipping
        q = shift_per_pressure(s.features)
        if before is None or q <= 0.0:
            continue
        if before == 0.0 < s.slipping:
            onsets["edge"].append(q)
        if before < 1.0 <= s.slipping:
            onsets["patch"].append(q)
    out: dict[str, Any] = {"slip_onsets": (len(onsets["edge"]), len(onsets["patch"]))}
    if onsets["edge"]:
        out["slip_edge_m_per_pa"] = float(np.median(onsets["edge"]))
    if len(onsets["edge"]) >= MIN_SPREAD_ONSETS:
        out["slip_edge_spread"] = float(np.std(onsets["edge"]) / np.median(onsets["edge"]))
    if onsets["patch"]:
        out["slip_patch_m_per_pa"] = float(np.median(onsets["patch"]))
    return out


def calibrate(samples: list[Sample], *, rig: str, source: str) -> Calibration:
    """Fit every method on ``samples`` (a rig's grasps with their true wrenches)."""
    return Calibration(
        rig=rig,
        source=source,
        physics=calibrate_physics(samples),
        ridge=calibrate_ridge(samples),
        friction=calibrate_friction(samples),
        **calibrate_slip(samples),
        samples=len(samples),
    )
