"""``python -m bench.pose_hard --quick``, ``python -m bench.pose --quick``,
``python -m bench.pose_weak --quick`` and ``python -m bench.pose_calib --quick`` run and
print their rows; the estimator is never silently wrong on them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench import pose, pose_calib, pose_hard, pose_weak
from bench.common import main


def test_pose_hard_quick(capsys: pytest.CaptureFixture[str]) -> None:
    rows = main("pose_hard", pose_hard.run, columns=pose_hard.COLUMNS, argv=["--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["rows"] and len(out["rows"]) == len(rows)
    kinds = {r["kind"] for r in rows}
    assert kinds == {"hard", "size", "degenerate", "coverage"}
    assert all("silent_wrong" in r and "object" in r for r in rows)
    assert sum(r["silent_wrong"] for r in rows) == 0
    hard = [r for r in rows if r["kind"] == "hard"]
    assert all(0.0 <= r["coverage95"] <= 1.0 and "right_suspect_share" in r for r in hard)
    # The coverage rows state how many estimates each cell holds and the binomial interval.
    coverage = [r for r in rows if r["kind"] == "coverage"]
    assert coverage and all(r["cases"] >= 3 for r in coverage)
    assert all(r["coverage95_lo"] <= r["coverage95"] <= r["coverage95_hi"] for r in coverage)
    fitted = [r for r in rows if r["kind"] == "size" and r["fit_dims"] == "radius"]
    assert fitted and fitted[0]["radius_err_mm_median"] < 0.5


def test_pose_weak_quick(capsys: pytest.CaptureFixture[str]) -> None:
    rows = main("pose_weak", pose_weak.run, columns=pose_weak.COLUMNS, argv=["--quick", "--json"])
    assert json.loads(capsys.readouterr().out)["rows"]
    for r in rows:
        assert r["cases"] == 3 and 0 <= r["right_ok"] <= r["right"] <= r["cases"]
        assert 0 <= r["silent_wrong"] <= r["cases"] - r["right"]
        assert r["weak_sd_deg_median"] > 0 and np.isfinite(r["weak_err_deg_rms"])
        assert np.isfinite(r["weak_z_rms"])
        assert r["ok_at_2deg"] <= r["ok_at_3deg"] <= r["ok_at_4deg"]


def test_pose_calib_quick(capsys: pytest.CaptureFixture[str]) -> None:
    rows = main("pose_calib", pose_calib.run, columns=pose_calib.COLUMNS, argv=["--quick"])
    assert "z2" in capsys.readouterr().out
    grid = [r for r in rows if r["kind"] == "grid"]
    # The quick grid's two sets, today's among them, scored best first.
    assert len(grid) == 2 and sum(r["current"] == "*" for r in grid) == 1
    keys = [(r["wrong_ok"], r["shapes_suspect"], r["z2"]) for r in grid]
    assert keys == sorted(keys)
    for chosen in ("chosen", "current"):
        (cell,) = [r for r in rows if r.get("set") == chosen]
        assert cell["cases"] == 3 and 0 <= cell["covered"] <= 3
        assert 0 <= cell["right_suspect"] <= cell["right"] <= 3
    # Fewer regions hold the truth when every share is smaller.
    wide, narrow = pose_calib.current(), {**pose_calib.current(), "face_error": 0.0}
    judged = pose_calib.collect(["box_corner"], [0.003], 2, 1000)
    assert judged and all(np.isfinite(j.differences).all() for j in judged)
    held = [pose_calib.score(judged, s)[0]["covered"] for s in (wide, narrow)]
    assert held[0] >= held[1]


def test_pose_quick_plot(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    rows = main(
        "pose",
        pose.run,
        columns=pose.COLUMNS,
        plot=pose.plot,
        argv=["--quick", "--plot", str(tmp_path / "pose.png")],
    )
    assert (tmp_path / "pose.png").stat().st_size > 0
    assert "silent_wrong" in capsys.readouterr().out
    estimator_rows = [r for r in rows if r["kind"] in ("accuracy", "basin", "hard")]
    assert all("silent_wrong" in r for r in estimator_rows)
    assert all("coverage95" in r for r in rows if r["kind"] == "accuracy")
    # A warm seed beside one solve, the judgement alone and a cold start, each with its
    # cost ratio; the warm seed near the answer is solved once.
    warm = {r["start"]: r for r in rows if r["kind"] == "warm_cost"}
    assert set(warm) == {"one_solve", "judgement", "warm_seed", "cold"}
    assert warm["one_solve"]["cost_vs_one_solve"] == 1.0
    assert warm["warm_seed"]["seeds_mean"] == 1.0 < warm["cold"]["seeds_mean"]
