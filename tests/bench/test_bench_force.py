"""Smoke test of ``python -m bench.force --quick``: every sweep gives its rows with
finite figures where the quick size has data; no figure is judged beyond its range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.bench import run_quick


@pytest.mark.timeout(600)
def test_quick_json_has_every_sweep() -> None:
    report, _ = run_quick("force", timeout=580)
    rows = report["rows"]
    sweeps = {r["sweep"] for r in rows}
    assert sweeps == {"wrench", "slip", "reflex", "handover"}
    wrench = [r for r in rows if r["sweep"] == "wrench"]
    assert {(r["world"], r["setting"], r["method"]) for r in wrench} == {
        (w, s, m)
        for w in ("sim", "mujoco", "mujoco_loaded")
        for s in ("fb_half", "fb_quarter", "dis_half")
        for m in ("physics", "ridge")
    }
    for r in wrench:
        assert r["samples"] > 0
        for key in ("force_err_n_median", "torque_err_nm_median", "ms_per_frame", "rate_hz"):
            assert math.isfinite(r[key]) and r[key] >= 0, (key, r)
        assert 0.0 <= r["within_goal_fraction"] <= 1.0
        # The dots against the object's slide: world.sim has that truth, MuJoCo not.
        shift_err = r["shift_err_mm_median"]
        assert (math.isfinite(shift_err) and shift_err >= 0) == (r["world"] == "sim"), r
    reflex = {(r["world"], r["setting"]): r for r in rows if r["sweep"] == "reflex"}
    assert set(reflex) == {(w, s) for w in ("sim", "mujoco") for s in ("off", "on")}
    assert all(r["kept"] + r["dropped"] == r["samples"] for r in reflex.values())
    assert all(0 <= r["dropped_at_bound"] <= r["dropped"] for r in reflex.values())
    for world in ("sim", "mujoco"):  # of the open loop's drops, the share kept
        on = reflex[(world, "on")]
        assert on["open_loop_dropped"] == reflex[(world, "off")]["dropped"]
        saved, within = on["saved_fraction"], on["saved_within_bound_fraction"]
        assert (0.0 <= saved <= 1.0) if on["open_loop_dropped"] else math.isnan(saved)
        assert math.isnan(within) or saved <= within <= 1.0, on
    handover = {r["method"]: r for r in rows if r["sweep"] == "handover"}
    assert set(handover) == {"shear", "force"}
    assert all(0.0 <= r["false_release_rate"] <= 1.0 for r in handover.values())
    slip = [r for r in rows if r["sweep"] == "slip"]
    assert {(r["world"], r["method"]) for r in slip} == {
        (w, m)
        for w in ("sim", "mujoco")
        for m in ("onset_edge", "onset_patch", "onset_edge_limit", "onset_patch_limit")
        + ("onset_edge_dots", "onset_patch_dots")
    }
    assert all(r["still_secs"] > 0 for r in slip)


def test_mujoco_slip_truth_and_its_calibration_file() -> None:
    from bench.force_mujoco import CALIBRATION, slipping_share
    from perception.force.estimators import Calibration

    # Under a third of the contact's points sliding is no slip (MuJoCo's soft friction
    # lets a point creep now and then); past 0.9 the whole patch slides; between, the
    # share is the slipping area's.
    assert [slipping_share(f) for f in (0.0, 0.25, 0.4, 0.7, 0.9, 1.0)] == [
        0.0, 0.0, 0.4, 0.7, 1.0, 1.0,
    ]  # fmt: skip
    cal = Calibration.load(CALIBRATION)
    assert cal.rig == "mujoco" and min(cal.slip_onsets) > 0
    assert 0 < cal.slip_edge_m_per_pa < cal.slip_patch_m_per_pa
    # Its shell's edge onsets spread too far for the stick limit to date one (the
    # dots' cue alone decides there, by default); world.sim's file knows its limit.
    from bench.force_data import CALIBRATION as SIM_CALIBRATION
    from perception.force.slip import SlipDetector

    assert SlipDetector.for_rig(cal).limit_cue is False
    assert SlipDetector.for_rig(Calibration.load(SIM_CALIBRATION)).limit_cue is True
    assert 0 < Calibration.load(SIM_CALIBRATION).slip_edge_spread < cal.slip_edge_spread


def test_mujoco_slip_truth_is_the_latex_sliding_over_the_object() -> None:
    from bench.force_mujoco import SLIP_SPEED_M_PER_S, sliding_share

    period = 1 / 30
    rng = np.random.default_rng(0)
    before = rng.uniform(-0.01, 0.01, (9, 3))  # material points, the object's frame
    touching = np.ones(9, bool)
    # A patch carried by the object (whatever the object does in the hand) stays put
    # in its frame: no point slides, however far the shell gives.
    assert sliding_share(before, before.copy(), touching, period) == 0.0
    # Three points creeping under the slip speed, three sliding over it.
    after = before.copy()
    after[:3, 1] += 0.5 * SLIP_SPEED_M_PER_S * period
    after[3:6, 2] += 2.0 * SLIP_SPEED_M_PER_S * period
    assert sliding_share(before, after, touching, period) == pytest.approx(1 / 3)
    # Points that did not touch the object in both frames do not count (a patch that
    # grows or shrinks moves its rim in and out of contact).
    touching[3:6] = False
    assert sliding_share(before, after, touching, period) == 0.0
    assert sliding_share(before, after, np.zeros(9, bool), period) == 0.0


def test_slip_sweep_references_at_the_stable_grasp() -> None:
    # On MuJoCo the hand lets go of the object the frame the jaws hold it with both
    # bubbles: its weight drops it 2-3 mm in 2-3 frames while the flow settles (the
    # core's reading overshoots a frame), before the grasp monitor calls the grasp
    # stable. The sweep referenced the detector one frame after the tare, inside that
    # drop: an onset with no slip to come was counted as a false alarm (a PET bottle's
    # pull: 1.97 mm of imprint lead in the frame the core read 4.3 mm, then 3.2 mm).
    # The slip node references at the stable grasp; so does the sweep now.
    from bench.force import slip_rows
    from bench.force_data import Frame, Recorded
    from perception.force.estimators import Calibration
    from perception.force.features import ContactFeatures

    cal = Calibration(
        rig="test", source="test", slip_edge_m_per_pa=1e-6, slip_patch_m_per_pa=1.3e-6
    )
    normal = np.array([-1.0, 0.0, 0.0])
    # Core shift (mm) per frame: tare at frame 0, the drop with an overshoot, held.
    core_mm = [0.0, 1.5, 3.4, 2.6, 2.5] + [2.5] * 40
    frames = []
    for i, c in enumerate(core_mm):
        shift = np.array([0.0, -c * 1e-3])
        feats = ContactFeatures(
            True, True, 3000.0, 900.0, 0.002, 8e-6, np.array([0.04, 0.0, 0.01]), normal,
            shift, shift, shift, 0.0, 500,
        )  # fmt: skip
        frames.append(
            Frame(
                t_secs=i / 30,
                features={"left": feats, "right": feats},
                force_n={s: np.array([6.0, 0.0, -2.0]) for s in ("left", "right")},
                torque_nm={s: np.zeros(3) for s in ("left", "right")},
                slipping={"left": 0.0, "right": 0.0},
                slide_m=shift.copy(),
                feature_secs=0.0,
                stable=i >= 6,  # the grasp monitor's dwell after the drop
            )
        )
    rows = slip_rows("test", [Recorded(frames)], cal, 1 / 30)
    assert rows[0]["still_secs"] > 0
    assert all(r["false_alarms_per_min"] == 0.0 for r in rows)


def test_recorded_frames_carry_the_default_settings_features() -> None:
    # The slip sweep reads each frame's own features with limits calibrated on the
    # default setting's: they must be that setting's (they were the first setting's,
    # Farneback, scored against a DIS calibration: every edge onset 6-15 frames early).
    from bench.force import record_all
    from bench.force_data import DEFAULT_SETTING

    rec = record_all(0, 0.2)
    assert len(rec.by_setting) == 3 and rec.frames
    for frame, feats in zip(rec.frames, rec.by_setting[DEFAULT_SETTING], strict=True):
        assert frame.features is feats


def test_reflex_runs_grasp_within_the_objects_bound() -> None:
    # The draws' grips (5-12 N) ignore the object's bound: the reflex sweep grasped a
    # wine glass at 11-11.6 N with its bound at 10 N (MuJoCo's seed 621, world.sim's
    # seed 22), so the reflex, which never commands past the bound, had nothing to
    # raise, and the drop was counted as the bound's. A reflex run grasps at most at
    # the bound; its load (scaled by the drawn grip) and every other draw are the same.
    from bench.force_data import OBJECTS, draw

    bound = OBJECTS["wine_glass"][3]
    for seed in (22, 621):
        free, bounded = draw(seed, load="fill"), draw(seed, load="fill", bounded=True)
        assert free.object == bounded.object == "wine_glass"
        assert free.grip_n > bound
        assert bounded.grip_n == bound
        assert bounded.scene.gripper.commands[0].force_n == bound
        assert bounded.doc["load"] == free.doc["load"]
    light = draw(21, load="fill")  # a wine glass drawn under its bound: unchanged
    assert light.grip_n < bound and draw(21, load="fill", bounded=True).doc == light.doc
