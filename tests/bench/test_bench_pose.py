"""``python -m bench.pose_hard --quick`` and ``python -m bench.pose --quick`` run and
print their rows; the estimator is never silently wrong on them."""

from __future__ import annotations

import json

import pytest

from bench import pose, pose_hard
from bench.common import main


def test_pose_hard_quick(capsys: pytest.CaptureFixture[str]) -> None:
    rows = main("pose_hard", pose_hard.run, columns=pose_hard.COLUMNS, argv=["--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["rows"] and len(out["rows"]) == len(rows)
    kinds = {r["kind"] for r in rows}
    assert kinds == {"hard", "size", "degenerate"}
    assert all("silent_wrong" in r and "object" in r for r in rows)
    assert sum(r["silent_wrong"] for r in rows) == 0
    fitted = [r for r in rows if r["kind"] == "size" and r["fit_dims"] == "radius"]
    assert fitted and fitted[0]["radius_err_mm_median"] < 0.5


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
