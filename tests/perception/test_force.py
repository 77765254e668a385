"""perception.force: features, the estimators and their calibration, slip, the reflex."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest

from geometry.camera import PinholeCamera
from perception.force.estimators import (
    Calibration,
    PhysicsCalibration,
    Sample,
    calibrate,
    calibrate_physics,
    calibrate_ridge,
    calibrate_slip,
    estimate,
    physics_wrench,
)
from perception.force.features import BubbleFeatures, ContactFeatures, rim_correction
from perception.force.reflex import GripReflex, PullWatch, ReflexParams
from perception.force.slip import SlipDetector
from runtime.params import build_params

LEFT_NORMAL = np.array([-1.0, 0.0, 0.0])


def features(
    *,
    pressure_pa: float = 2000.0,
    area_m2: float = 0.002,
    shift_m: tuple[float, float] = (0.0, 0.0),
    core: tuple[float, float] | None = None,
    edge: tuple[float, float] | None = None,
    centroid: tuple[float, float, float] = (0.04, 0.0, 0.01),
    volume_m3: float = 8e-6,
    rise_pa: float = 900.0,
) -> ContactFeatures:
    s = np.asarray(shift_m, float)
    return ContactFeatures(
        True, True, pressure_pa, rise_pa, area_m2, volume_m3, np.asarray(centroid, float),
        LEFT_NORMAL, s, np.asarray(core if core is not None else s, float),
        np.asarray(edge if edge is not None else s, float), 0.0, 500,
    )  # fmt: skip


def test_physics_model_presses_along_the_plate_and_shears_with_the_dots() -> None:
    cal = PhysicsCalibration(gain=1.0, stiffness_n_per_m3=(1e6, 1e6))
    w = physics_wrench(features(shift_m=(-0.001, 0.0)), cal)
    # The object pushes the left membrane towards its plate (+x) with p A.
    assert w.force_n[0] == pytest.approx(2000.0 * 0.002)
    assert w.force_n[1] == pytest.approx(-1e6 * 0.002 * 0.001)
    np.testing.assert_allclose(w.torque_nm, np.cross([0.04, 0.0, 0.01], w.force_n))
    out = dataclasses.replace(features(), in_contact=False)
    assert not np.any(physics_wrench(out, cal).force_n)


def test_calibration_recovers_the_constants_of_a_physics_world() -> None:
    rng = np.random.default_rng(0)
    truth = PhysicsCalibration(gain=1.3, stiffness_n_per_m3=(8e5, 1.2e6))
    data = []
    for _ in range(60):
        f = features(
            pressure_pa=float(rng.uniform(1200, 4000)),
            area_m2=float(rng.uniform(0.001, 0.003)),
            shift_m=tuple(rng.uniform(-0.003, 0.003, 2)),
            volume_m3=float(rng.uniform(2e-6, 2e-5)),
            rise_pa=0.0,
        )
        w = physics_wrench(f, truth)
        data.append(Sample("left", f, w.force_n, w.torque_nm))
    fitted = calibrate_physics(data)
    assert fitted.gain == pytest.approx(1.3, rel=1e-6)
    assert fitted.stiffness_n_per_m3 == pytest.approx((8e5, 1.2e6), rel=1e-6)
    assert max(fitted.force_sigma_n) < 1e-6
    with pytest.raises(ValueError, match="at least 4"):
        calibrate_physics(data[:2])


def test_ridge_strength_is_the_one_that_reads_left_out_grasps_best() -> None:
    """The ridge's 35 features are products of a few measurements, nearly collinear
    over a few grasps: with a fixed weak strength (1e-3 n) the fit follows what tells
    its grasps apart, and reads a grasp it was not fitted on far off (MuJoCo's refit on
    the core's median read the fill graph's mug 27% further off than the file before it,
    on the same features). The strength is chosen leaving one grasp out at a time: where
    the features do not explain the force (noise about a constant) the strongest, and a
    grasp left out is read closer than with the weak one; where they explain it exactly
    (a physics world) the weakest."""
    rng = np.random.default_rng(4)
    truth = PhysicsCalibration(gain=1.1, stiffness_n_per_m3=(6e5, 6e5))
    drawn = [
        features(
            pressure_pa=float(rng.uniform(1500, 4000)),
            area_m2=float(rng.uniform(0.001, 0.003)),
            shift_m=tuple(rng.uniform(-0.003, 0.003, 2)),
            volume_m3=float(rng.uniform(4e-6, 2e-5)),
            centroid=(0.04, *rng.normal(0, 0.005, 2)),
        )
        for _ in range(160)
    ]
    noise = [Sample("left", f, np.array([4.0, 1.0, -1.0]) + rng.normal(0, 0.3, 3), np.zeros(3),
                    0.0, i // 20) for i, f in enumerate(drawn)]  # fmt: skip
    fitted, left_out = noise[:120], noise[120:]
    chosen = calibrate(fitted, rig="test", source="synthetic")
    assert chosen.ridge.ridge == 1.0

    def error(cal: Calibration) -> float:
        return float(
            np.median(
                [np.linalg.norm(estimate(s.features, "left", cal, "ridge").force_n - s.force_n)
                 for s in left_out]
            )
        )  # fmt: skip

    weak = dataclasses.replace(chosen, ridge=calibrate_ridge(fitted, 1e-3))
    assert error(chosen) < 0.9 * error(weak)
    exact = [
        Sample("left", f, physics_wrench(f, truth).force_n, np.zeros(3), 0.0, i // 20)
        for i, f in enumerate(drawn)
    ]
    assert calibrate_ridge(exact).ridge == 1e-3
    # Two grasps leave too little out to choose with: the weakest strength.
    assert calibrate_ridge(noise[:40]).ridge == 1e-3


def test_calibration_file_round_trips_and_a_bad_one_names_the_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    data = []
    for i in range(80):
        f = features(
            area_m2=float(rng.uniform(0.001, 0.003)), shift_m=tuple(rng.uniform(-0.002, 0.002, 2))
        )
        force = np.array([f.pressure_pa * f.area_m2, *(1e6 * f.area_m2 * f.shift_m)])
        data.append(Sample("left" if i % 2 else "right", f, force, np.zeros(3)))
    cal = calibrate(data, rig="test", source="synthetic")
    path = tmp_path / "cal.json"
    cal.save(path)
    again = Calibration.load(path)
    f = data[0].features
    for method in ("physics", "ridge"):
        np.testing.assert_allclose(
            estimate(f, "left", again, method).force_n, estimate(f, "left", cal, method).force_n
        )
    with pytest.raises(ValueError, match="unknown method"):
        estimate(f, "left", cal, "oracle")
    # A file from before the slip limits: world.sim's defaults.
    old = json.loads(cal.to_json())
    for key in ("slip_edge_m_per_pa", "slip_patch_m_per_pa", "slip_onsets"):
        del old[key]
    older = Calibration.from_dict(old)
    assert older.slip_edge_m_per_pa == Calibration().slip_edge_m_per_pa > 0
    path.write_text(json.dumps({"physics": {"stiffness": 1}}))
    with pytest.raises(ValueError, match=str(path)):
        Calibration.load(path)
    with pytest.raises(ValueError, match="missing.json"):
        Calibration.load(tmp_path / "missing.json")


def test_features_are_finite_without_reference_without_contact_and_with_nan_depth() -> None:
    camera = PinholeCamera.from_fov(64, 48, hfov_deg=62.0, vfov_deg=45.0)
    pose = np.eye(4)
    pose[0, 3] = 0.05
    ir = np.full((48, 64), 1000, np.uint16)
    depth = np.full((48, 64), 0.06, np.float32)
    ext = BubbleFeatures()
    f = ext.update(ir, depth, 1000.0, camera, pose)
    assert not f.in_contact and f.area_m2 == 0.0 and np.isfinite(f.normal_in_tool).all()
    ext.free_frame(depth, 1000.0)
    assert not ext.update(ir, depth, 1000.0, camera, pose).in_contact
    nan = np.full_like(depth, np.nan)
    f = ext.update(ir, nan, 1000.0, camera, pose)
    assert not f.in_contact and np.isfinite(f.shift_m).all()
    # A patch pressed in, but too small to track the dots on: no tangential measurement.
    pressed = depth.copy()
    pressed[20:30, 28:38] -= 0.004
    ext.tare(ir, depth, camera, pose)
    f = ext.update(ir, pressed, 1200.0, camera, pose)
    assert f.in_contact and f.area_m2 > 0 and f.pressure_rise_pa == pytest.approx(200.0)
    assert f.normal_in_tool.tolist() == [-1.0, 0.0, 0.0]


def test_rim_correction_is_the_cylinder_band_ratio_and_finite_when_shallow() -> None:
    assert rim_correction(np.array([0.004] * 20), 0.001) == pytest.approx(np.sqrt(4 / 3))
    assert np.isfinite(rim_correction(np.array([0.001]), 0.001))
    assert rim_correction(np.array([np.nan]), 0.001) == 1.0


def run_detector(
    shifts: list[tuple[float, float]],
    forces: list[float],
    pressure_pa: float = 2000.0,
    imprint: list[tuple[float, float]] | None = None,
) -> list[str]:
    """Onsets of a detector whose rig's edge slips at 0.7 um/Pa of the core's shift and
    its whole patch at 0.95 um/Pa (at 2 kPa: 1.4 mm and 1.9 mm; it fires at 0.98 of the
    edge's and 1.1 of the patch's); ``imprint``: the patch's centroid (tool y, z) per
    frame (still by default)."""
    cal = Calibration(slip_edge_m_per_pa=0.7e-6, slip_patch_m_per_pa=0.95e-6, friction=0.8)
    det = SlipDetector.for_rig(cal)
    det.reference()
    onsets = []
    for i, ((core, edge), ft) in enumerate(zip(shifts, forces, strict=True)):
        y, z = imprint[i] if imprint is not None else (0.0, 0.01)
        f = features(
            core=(core, 0.0), edge=(edge, 0.0), shift_m=(core, 0.0), pressure_pa=pressure_pa,
            centroid=(0.04, y, z),
        )  # fmt: skip
        report = det.update(f, np.array([4.0, ft, 0.0]), i / 30)
        onsets.append(report.onset)
    return onsets


def test_slip_detector_fires_at_the_pressures_limit_edge_then_patch() -> None:
    # The core's shift grows 0.1 mm a frame: 1.372 mm (0.98 x 0.7 um/Pa x 2 kPa) at frame
    # 14, 2.09 mm (1.1 x 0.95 um/Pa x 2 kPa) at frame 21; the force estimate says
    # nothing of it (a light, constant load), the imprint does not move (a slide it
    # cannot see: the shift's backstop decides).
    shifts = [(0.0001 * i, 0.0001 * i) for i in range(25)]
    onsets = run_detector(shifts, [0.5] * 25)
    assert onsets.index("edge") == 14 and onsets.index("patch") == 21
    assert onsets.count("edge") == 1 and onsets.count("patch") == 1
    # A firmer grip (twice the pressure) doubles the limits: the same shifts stick.
    assert not any(run_detector(shifts, [0.5] * 25, pressure_pa=4000.0))


def test_slip_detector_sees_the_edge_lag_near_the_limit() -> None:
    # The edge stalls while the core goes on; at 0.96 of the edge's limit (1.344 mm, past
    # the 0.95 that confirms) the lag calls an edge slip the strain alone (0.98) has not
    # reached.
    shifts = [(0.0001 * i, 0.0001 * i) for i in range(10)]
    shifts += [(0.00125 + 0.00003 * i, 0.00100) for i in range(5)]
    onsets = run_detector(shifts, [0.5] * 15)
    assert onsets.count("edge") == 1 and onsets.index("edge") == 13, onsets
    assert "patch" not in onsets


def test_slip_detector_sees_the_whole_patch_slide_by_its_imprint() -> None:
    # The object moves 0.1 mm a frame along y; the core's dots and the imprint go with
    # it (stick) to 0.9 mm, then the dots stop short of the patch's limit (the whole
    # patch slides: the latex stays at its limit) while the imprint runs on, 0.2 mm a
    # frame. The imprint has run 0.5 mm ahead over the window 3 frames later, long
    # before the dots' shift could reach the backstop (it never does).
    n = 20
    core = [min(0.0001 * i, 0.0009) for i in range(n)]
    shifts = [(c, c) for c in core]
    imprint = [(0.0001 * i if i <= 9 else 0.0009 + 0.0002 * (i - 9), 0.01) for i in range(n)]
    onsets = run_detector(shifts, [0.5] * n, imprint=imprint)
    assert onsets.count("patch") == 1 and onsets.index("patch") == 12, onsets
    # Stuck, the same motion: the imprint and the dots agree, nothing slips.
    stuck = [(0.0001 * i * 0.45, 0.0001 * i * 0.45) for i in range(n)]
    assert not any(run_detector(stuck, [0.5] * n, imprint=[(s, 0.01) for s, _ in stuck]))


def test_slip_detector_reads_no_slide_from_an_imprint_that_cannot_move() -> None:
    # A cylinder pulled along its axis (tool z here: the dots move along y in these
    # features, the imprint not at all but its jitter, 0.05 mm as on the bench's
    # grasps): the dots' motion off the imprint's direction is no lead.
    rng = np.random.default_rng(3)
    n = 30
    shifts = [(0.00004 * i, 0.00004 * i) for i in range(n)]
    imprint = [(float(a), 0.01 + float(b)) for a, b in rng.normal(0, 0.00005, (n, 2))]
    assert not any(run_detector(shifts, [0.5] * n, imprint=imprint))


def test_slip_detector_reads_no_slide_from_an_imprint_moving_against_the_latex() -> None:
    """A mug pulled on world.mujoco's shell (loaded grasp 4): the object and its latex
    move on together, 0.1 mm a frame (the shell gives), while the patch changes shape
    and its imprint drifts the other way, 0.15 mm a frame. Measured along the imprint's
    motion the dots ran 0.4 mm behind it, which read as the whole patch sliding 20
    frames before the latex slid. An imprint moving against the latex's stretch while
    the dots carry the stretch on is the patch changing shape under a stuck latex."""
    n = 12
    shifts = [(0.0002 + 0.0001 * i, 0.0002 + 0.0001 * i) for i in range(n)]
    imprint = [(-0.00015 * i, 0.01) for i in range(n)]
    assert not any(run_detector(shifts, [0.5] * n, imprint=imprint))
    # Once the whole patch slides the dots stop, and the imprint may run against the
    # stretch (world.sim's PET bottle being filled, seed 3: its taper on the curved
    # membrane): that is a slide, 3 frames after the dots stopped.
    stopped = [(min(0.0002 + 0.0001 * i, 0.0008), 0.0008) for i in range(n)]
    imprint = [(-0.0002 * max(0, i - 6), 0.01) for i in range(n)]
    onsets = run_detector(stopped, [0.5] * n, imprint=imprint)
    assert onsets.count("patch") == 1 and onsets.index("patch") == 9, onsets


def test_slip_detector_takes_the_whole_patchs_limit_only_where_the_calibration_knows_it() -> None:
    """The whole patch's backstop (the core's shift past 1.1 of its limit) is a stick
    limit too: on world.mujoco's shell, whose limits spread 16-22% with the object and
    the load's direction, it fired on a mug pulled 18 frames before its latex slid. As
    the edge's limit, it decides only where the calibration's edge onsets spread at
    most ``limit_max_spread``; elsewhere the imprint and the dots do."""
    for spread, fires in ((0.05, True), (0.2, False)):
        cal = Calibration(
            slip_edge_m_per_pa=1.5e-6, slip_patch_m_per_pa=1.9e-6, friction=0.8,
            slip_edge_spread=spread,
        )  # fmt: skip
        detector = SlipDetector.for_rig(cal)
        detector.reference()
        onsets = []
        for i in range(30):  # the core's shift to 1.3 of the whole patch's limit at 2 kPa
            f = features(core=(0.00005 + 0.00017 * i, 0.0))
            onsets.append(detector.update(f, np.array([4.0, 0.5, 0.0]), i / 30).onset)
        assert ("patch" in onsets) == fires, (spread, onsets)


def test_slip_detector_stays_quiet_while_held_still_with_noise() -> None:
    rng = np.random.default_rng(2)
    noise = rng.normal(0, 0.00003, (300, 2))
    onsets = run_detector([tuple(n) for n in noise], [1.0] * 300)
    assert not any(onsets)


def test_slip_detector_stays_quiet_on_a_mujoco_imprints_jitter() -> None:
    # A wine glass held still on world.mujoco (12 mm membrane mesh): the imprint (the
    # patch's centroid, tool y and z, mm from the first frame) jitters by up to 0.3 mm
    # from frame to frame while the dots stay put (recorded). Taken from one frame at
    # each end of the window, frames 10 and 14 read 0.54 mm of lead: a whole-patch
    # onset with no slip. Means over two frames at each end stay under the cue.
    imprint_mm = [
        (0.0, 0.0), (0.09, -0.01), (0.04, 0.03), (0.04, 0.07), (0.01, 0.05), (0.0, -0.21),
        (-0.06, -0.04), (-0.08, 0.04), (0.04, 0.22), (0.02, -0.18), (0.11, 0.29),
        (-0.06, -0.14), (0.04, -0.17), (0.14, 0.06), (-0.03, -0.23), (0.12, 0.05),
        (-0.02, 0.01), (-0.06, -0.04),
    ]  # fmt: skip
    detector = SlipDetector(edge_m_per_pa=1.5e-6, patch_m_per_pa=1.9e-6)
    detector.reference()
    core = (-0.00312, -0.00012)  # 1.07 um/Pa: under the edge's limit
    onsets = []
    for i, (y, z) in enumerate(imprint_mm):
        f = features(
            pressure_pa=2910.0, core=core, centroid=(0.04, 0.0035 + y / 1e3, -0.002 + z / 1e3)
        )
        onsets.append(detector.update(f, np.array([3.0, 0.0, 0.0]), i / 30).onset)
    assert not any(onsets)


def test_slip_detector_ignores_a_force_estimate_that_reads_the_load_high() -> None:
    # A firm hold (the dots 0.6 mm off, half the edge's limit) whose force estimate
    # reads the tangential load at 0.73 of the friction cone (4 N normal, friction 0.8):
    # the bench's still holds of a PET bottle, where the force estimate read 35% high.
    # The detector judged by that estimate called it a slip every time.
    onsets = run_detector([(0.0006, 0.0006)] * 100, [0.73 * 0.8 * 4.0] * 100)
    assert not any(onsets)


def test_slip_limits_are_calibrated_at_the_truths_onsets() -> None:
    # A bubble whose edge begins to slip at a core shift of 0.8 um/Pa and its whole
    # patch at 1.1 um/Pa (pressure 2 kPa), two grasps in time order.
    data = []
    for _ in range(2):
        for i in range(30):
            shift = 0.0001 * i
            q = shift / 2000.0
            slipping = 0.0 if q < 0.8e-6 - 1e-12 else (1.0 if q >= 1.1e-6 - 1e-12 else 0.4)
            f = features(shift_m=(shift, 0.0), pressure_pa=2000.0)
            data.append(Sample("left", f, np.zeros(3), np.zeros(3), slipping))
    out = calibrate_slip(data)
    assert out["slip_onsets"] == (2, 2)
    assert out["slip_edge_m_per_pa"] == pytest.approx(0.8e-6)
    assert out["slip_patch_m_per_pa"] == pytest.approx(1.1e-6)
    assert calibrate_slip(data[:10]) == {"slip_onsets": (0, 0)}  # no onset: the defaults
    with pytest.raises(ValueError, match="slip_edge_m_per_pa"):
        Calibration(slip_edge_m_per_pa=0.0)


def test_reflex_raises_to_what_the_load_needs_bounded_and_not_twice_at_once() -> None:
    reflex = GripReflex(ReflexParams(max_force_n=12.0, cooldown_secs=0.1), 6.0, 0.8)
    assert reflex.on_slip(1.0, 8.0) == pytest.approx(9.0)  # 1.5 x 6 N beats the 8 N needed
    assert reflex.on_slip(1.05, 20.0) is None  # cooling down
    assert reflex.on_slip(1.2, 20.0) == 12.0  # the object's bound
    assert reflex.on_slip(1.5, 30.0) is None
    with pytest.raises(ValueError, match="max_force_n"):
        build_params(ReflexParams, {"max_force_n": 100.0})


def test_pull_is_told_from_a_heavier_load_by_its_direction() -> None:
    watch = PullWatch(0.6, 2, gravity_in_tool=(0.0, -1.0, 0.0))
    watch.start(np.array([0.0, 3.4, 0.0]))
    # Filling: the bubbles push the object up harder.
    assert not any(watch.update(np.array([0.0, 3.4 + d, 0.0])) for d in (1.0, 2.0, 3.0))
    # A squeeze changes only the closing axis.
    assert not watch.update(np.array([5.0, 3.4, 0.0]))
    # A pull out along +z: the bubbles hold back along -z.
    assert not watch.update(np.array([0.0, 3.4, -0.8]))
    assert watch.update(np.array([0.0, 3.4, -1.0]))


@pytest.mark.slow
def test_dots_follow_the_object_and_the_edge_slip_is_seen_on_the_square_bottle() -> None:
    """While the patch sticks, the core's dots move with the object: their shift since
    the tare is the object's slide in the hand since then. On the square bottle's flat
    face (a large patch partly seen at grazing angles) DIS at half resolution read a
    third of it, and the detector saw the edge slip 23 frames late (a miss). Its whole
    patch slides from frame 73: the dots' shift, which the flow loses once the edge
    slips (it falls while the object slides on), saw it 9 frames late; the imprint
    running ahead of the dots sees it within 2."""
    tare: dict[str, np.ndarray] = {}
    read: dict[str, float] = {}
    truth: dict[str, float] = {}

    def watch(side: str, f: Any, snap: Any, slipping: bool) -> None:
        tare.setdefault(side, snap.slide_m.copy())
        if not slipping:  # all of the patch has stuck
            read[side] = float(np.hypot(*f.core_shift_m))
            truth[side] = float(np.hypot(*(snap.slide_m - tare[side])))

    spec, onset, truth_onset, frame = fill_onsets(6, 2.6, watch)
    assert spec.object == "square_bottle" and spec.load == "fill"
    for side in ("left", "right"):
        assert truth[side] > 0.003  # the load moved the object 3 mm on the latex
        assert read[side] == pytest.approx(truth[side], rel=0.15), side
        # Found, and not late (the limits spread: a low one fires a few frames early).
        assert -6 <= onset.get(side, frame) - truth_onset[side] <= 2, (side, onset, truth_onset)
        whole = f"{side} patch"
        assert abs(onset.get(whole, frame) - truth_onset[whole]) <= 2, (onset, truth_onset)


def fill_onsets(
    seed: int, duration_secs: float, watch: Callable[[str, Any, Any, bool], None] | None = None
) -> tuple[Any, dict[str, int], dict[str, int], int]:
    """The auto-labeller's scene ``seed`` on world.sim through a slip detector per bubble
    (the physics wrench): the scene, the frame of each onset (``side``, and ``"side
    KIND"``) and of the truth's (``side``: the edge; ``"side patch"``: the whole patch),
    and the frames run. ``watch(side, frame, snapshot, slipping)`` sees each tracked
    bubble-frame, ``slipping`` whether its edge has slipped."""
    from bench.force_data import CALIBRATION, Bubbles, draw
    from perception.force.features import FeatureParams
    from sim import Simulator

    spec = draw(seed, duration_secs=duration_secs)
    cal = Calibration.load(CALIBRATION)
    simulator = Simulator(spec.scene)
    bubbles = Bubbles(FeatureParams().flow)
    detectors = {s: SlipDetector.for_rig(cal) for s in ("left", "right")}
    referenced: set[str] = set()
    onset: dict[str, int] = {}
    truth_onset: dict[str, int] = {}
    frame = 0
    while not simulator.world.done:
        inst = simulator.step()
        snap = inst.snapshot
        for side, f in bubbles.frame(inst, spec.scene).items():
            if f.tracked and side not in referenced:
                referenced.add(side)
                detectors[side].reference()
            force = estimate(f, side, cal, "physics").force_n
            report = detectors[side].update(f, force, snap.time_secs)
            if report.onset:
                onset.setdefault(side, frame)
                onset.setdefault(f"{side} {report.onset}", frame)
            if snap.wrench[side].slipping_fraction > 0.0:
                truth_onset.setdefault(side, frame)
            if snap.wrench[side].slipping_fraction >= 1.0:
                truth_onset.setdefault(f"{side} patch", frame)
            if watch is not None and f.tracked:
                watch(side, f, snap, side in truth_onset)
        frame += 1
    return spec, onset, truth_onset, frame


def test_departing_share_is_the_share_of_the_patch_leaving_its_rigid_motion() -> None:
    from perception.force.slide import departing_share

    # A 30 mm patch of dots every 0.5 mm, moving with the object: 3 mm/s along y and a
    # turn of 0.1 rad/s about the plate's normal, with 0.5 mm/s of flow noise per dot.
    rng = np.random.default_rng(4)
    g = np.arange(-0.015, 0.015, 0.0005)
    at = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    rigid = np.array([0.003, 0.0]) + 0.1 * np.stack([-at[:, 1], at[:, 0]], axis=1)
    noisy = rigid + rng.normal(0, 0.0005, at.shape)

    def share(v: np.ndarray) -> float:
        return departing_share(at, v, cell_m=0.003, speed_m_per_s=0.0015)

    assert share(noisy) < 0.05  # stuck: it moves as one, however fast
    # The rim slides: its dots stop (the object moves on over them). A band 9 mm wide
    # along one side is 30% of the patch; the rest still moves as one.
    rim = at[:, 0] > 0.0058
    slid = noisy.copy()
    slid[rim] = rng.normal(0, 0.0005, (int(rim.sum()), 2))
    assert rim.mean() == pytest.approx(0.3, abs=0.01)
    assert share(slid) == pytest.approx(rim.mean(), abs=0.05)
    # Under the speed that counts (1.5 mm/s off the rigid motion): no departure.
    crept = rigid.copy()
    crept[rim] -= np.array([0.001, 0.0])
    assert share(crept) == 0.0
    # Too few dots to tell: nothing.
    assert departing_share(at[:3], rigid[:3], cell_m=0.003, speed_m_per_s=0.0015) == 0.0


SHARES = [0.05] * 10 + [0.12, 0.2, 0.3, 0.35, 0.3] + [0.08] * 8  # dots departing, a frame each


def dots_run(
    cal: Calibration, core_m: float, cue: Literal["both", "limit", "dots"] | None = None
) -> tuple[list[str], str]:
    """Onsets (and the last phase) of a detector on the rig ``cal`` (with ``edge_cue``
    ``cue``, the default's without) whose core's shift stays at ``core_m`` while the
    share of the dots leaving the patch's rigid motion follows :data:`SHARES`."""
    from perception.force.slip import SlipParams

    detector = SlipDetector.for_rig(cal, SlipParams(edge_cue=cue) if cue else None)
    detector.reference()
    onsets = []
    for i, s in enumerate(SHARES):
        f = dataclasses.replace(features(core=(core_m, 0.0)), departing_share=s)
        onsets.append(detector.update(f, np.array([4.0, 0.5, 0.0]), i / 30).onset)
    return onsets, detector.phase


def test_slip_detector_by_the_dots_needs_no_stick_limit() -> None:
    """world.mujoco's shell: the core's shift per pascal at which the latex begins to
    slide spreads 0.83-2.29 um/Pa over objects and load directions, so a rig's limit
    fires on a firm hold whose limit is high (a mug pulled: 22 frames before its latex
    slid) and late on a low one. With ``edge_cue: dots`` the edge slips when a quarter
    of the patch's dots leave its rigid motion, whatever the shift."""
    cal = Calibration(slip_edge_m_per_pa=1.5e-6, slip_patch_m_per_pa=1.9e-6, friction=0.8)
    # The core's shift at 1.3 of the edge's limit (2 kPa: 3.9 mm) and still: the limit's
    # cue calls it an edge slip from the first frame; the dots say the patch sticks.
    cues: tuple[tuple[Literal["limit", "dots"], int], ...] = (("limit", 0), ("dots", 12))
    for cue, first in cues:
        onsets, phase = dots_run(cal, 0.0039, cue)
        assert onsets.index("edge") == first and onsets.count("edge") == 1, (cue, onsets)
        assert "patch" not in onsets
        # The dots' episode ends once they move as one again (5 frames under half).
        assert phase == ("edge" if cue == "limit" else "stick"), cue


def test_slip_detector_by_default_takes_the_limit_only_where_the_calibration_knows_it() -> None:
    """The default edge cue (``both``): the earlier of the dots' and the limit's, the
    limit's only where the calibration's edge onsets spread little (world.sim: 3-5%
    about their median; world.mujoco's shell: 16-22%, where a core shift at 1.3 of the
    median limit is a firm hold as often as a slip)."""
    from perception.force.slip import SlipParams

    assert SlipParams().edge_cue == "both"
    for spread, first in ((0.05, 0), (0.2, 12)):
        cal = Calibration(
            slip_edge_m_per_pa=1.5e-6, slip_patch_m_per_pa=1.9e-6, friction=0.8,
            slip_edge_spread=spread,
        )  # fmt: skip
        onsets, _ = dots_run(cal, 0.0039)
        assert onsets.index("edge") == first and onsets.count("edge") == 1, (spread, onsets)
    # Where the limit is known, the dots confirm it from 0.95 of it, as the edge's lag
    # does (at 0.96 here: 2.88 mm); far below it (0.5) no point of the latex slides, and
    # dots departing there are the flow's error (the square bottle's face seen at
    # grazing angles read a quarter of its dots departing 7 frames before its edge slid).
    cal = Calibration(slip_edge_m_per_pa=1.5e-6, slip_patch_m_per_pa=1.9e-6, slip_edge_spread=0.05)
    cores: tuple[tuple[float, int | None], ...] = ((0.00288, 12), (0.0015, None))
    for core, found in cores:
        onsets, _ = dots_run(cal, core)
        assert (onsets.index("edge") if "edge" in onsets else None) == found, (core, onsets)


def test_calibration_measures_the_edge_limits_spread() -> None:
    # Three grasps whose edges begin to slip at 0.8, 1.0 and 1.2 um/Pa of the core's
    # shift (2 kPa): the spread is their standard deviation over their median.
    data = []
    for limit in (0.8e-6, 1.0e-6, 1.2e-6):
        for i in range(30):
            shift = 0.0001 * i
            slipping = 0.4 if shift / 2000.0 >= limit - 1e-12 else 0.0
            f = features(shift_m=(shift, 0.0), pressure_pa=2000.0)
            data.append(Sample("left", f, np.zeros(3), np.zeros(3), slipping))
        data.append(Sample("left", features(pressure_pa=2000.0), np.zeros(3), np.zeros(3), 0.0))
    out = calibrate_slip(data)
    assert out["slip_onsets"][0] == 3
    assert out["slip_edge_spread"] == pytest.approx(np.std([0.8, 1.0, 1.2]) / 1.0, rel=1e-6)
    assert "slip_edge_spread" not in calibrate_slip(data[:62])  # two onsets: not measured
    with pytest.raises(ValueError, match="slip_edge_spread"):
        Calibration(slip_edge_spread=-0.1)


@pytest.mark.slow
def test_core_reads_the_objects_slide_where_one_end_of_the_patch_misreads() -> None:
    """The wine glass being filled (world.sim, seed 9): its load moves it along tool y
    and z. While the patch sticks, the core's dots read the object's slide in the hand,
    but the end of the patch the object slides towards reads a fraction of the slide
    along z (0.4 of 1.4 mm at frame 60, the left bubble); the core's mean dragged with
    it read 19% short (1.14 mm), which dated the edge's slip early or late by how much
    of the core that end was. The core's median reads the object's slide."""
    from bench.force_data import Bubbles, draw
    from perception.force.features import FeatureParams
    from sim import Simulator

    spec = draw(9, duration_secs=2.1)
    assert spec.object == "wine_glass" and spec.load == "fill"
    simulator = Simulator(spec.scene)
    bubbles = Bubbles(FeatureParams().flow)
    tare: dict[str, np.ndarray] = {}
    errors: dict[str, list[float]] = {"left": [], "right": []}
    while not simulator.world.done:
        inst = simulator.step()
        snap = inst.snapshot
        for side, f in bubbles.frame(inst, spec.scene).items():
            if f.tracked and side not in tare:
                tare[side] = snap.slide_m.copy()
            slide = snap.slide_m - tare.get(side, snap.slide_m)
            if f.tracked and snap.wrench[side].slipping_fraction == 0.0 and np.hypot(*slide) > 1e-3:
                errors[side].append(
                    float(np.linalg.norm(f.core_shift_m - slide) / np.hypot(*slide))
                )
    for side, errs in errors.items():
        assert len(errs) >= 15, side  # 1 mm and more of stuck slide, frame after frame
        assert max(errs) < 0.05, (side, np.round(errs, 3))


@pytest.mark.slow
def test_edge_onset_on_world_sim_is_dated_within_a_frame() -> None:
    """world.sim's truth dates the edge's slip where its stick model says: the first
    sample past ``friction p / (k g)``, the rim's (``g`` = 2), at 0.89-0.91 um/Pa of
    the object's slide on every slipping bubble of seeds 0-15. With the core's dots
    reading that slide, the rig's limit is known to about 1%, and the detector dates
    the onset within a frame; at 0.92 of a limit taken from the core's mean it fired
    3-4 frames early on this PET bottle being filled (seed 15)."""
    spec, onset, truth_onset, frame = fill_onsets(15, 2.3)
    assert spec.object == "pet_bottle" and spec.load == "fill"
    for side in ("left", "right"):
        assert frame - truth_onset[side] >= 5, truth_onset  # the edge slips in the recording
        assert abs(onset.get(side, frame) - truth_onset[side]) <= 1, (side, onset, truth_onset)
