"""Smoke test of ``python -m bench.force --quick``: every sweep gives its rows with
finite figures where the quick size has data; no figure is judged beyond its range."""

from __future__ import annotations

import math

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
        (w, m) for w in ("sim", "mujoco") for m in ("onset_edge", "onset_patch")
    }
    assert all(r["still_secs"] > 0 for r in slip)


def test_mujoco_slip_truth_and_its_calibration_file() -> None:
    from bench.force_mujoco import CALIBRATION, slipping_share
    from perception.force.estimators import Calibration

    # The rim alone at its cone (under half the contacts) is no slip; past 0.9 the whole
    # patch slides; between, the share is the slipping area's.
    assert [slipping_share(f) for f in (0.0, 0.25, 0.5, 0.7, 0.9, 1.0)] == [
        0.0, 0.0, 0.5, 0.7, 1.0, 1.0,
    ]  # fmt: skip
    cal = Calibration.load(CALIBRATION)
    assert cal.rig == "mujoco" and min(cal.slip_onsets) > 0
    assert 0 < cal.slip_edge_m_per_pa < cal.slip_patch_m_per_pa


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
