"""Smoke test of ``bench/rig.py`` (--quick): calibration recovers the as-built rig and helps.

The bench's own targets are asserted on its quick run: the mounts within 0.3 degrees and
0.3 mm, each pressure zero within one count of the sensor.
"""

from __future__ import annotations

import pytest

from tests.bench import run_quick

pytestmark = pytest.mark.timeout(600)


def test_quick_calibration_recovers_the_rig_and_improves_the_pose() -> None:
    report, _ = run_quick("rig", "--no-plot", timeout=400)
    rows = report["rows"]
    mounts = [r for r in rows if r["case"] == "mount"]
    assert [r["side"] for r in mounts] == ["left", "right"]
    for row in mounts:
        assert row["before_deg"] == pytest.approx(2.0, abs=0.05)
        assert row["before_mm"] == pytest.approx(2.0, abs=0.05)
        assert row["after_deg"] < 0.3 and row["after_mm"] < 0.3, row
    for row in (r for r in rows if r["case"] == "pressure"):
        assert row["error_pa"] < row["resolution_pa"], row
    pose = {r["mounts"]: r for r in rows if r["case"] == "pose"}
    assert pose["calibrated"]["offaxis_mm_median"] < pose["cad"]["offaxis_mm_median"]
    assert pose["calibrated"]["axis_deg_median"] < pose["cad"]["axis_deg_median"]
