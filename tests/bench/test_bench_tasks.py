"""Smoke test of ``python -m bench.tasks``: one stacking scene runs and the JSON has the
promised shape (task, success rate, latencies). No figure is judged beyond being there."""

from __future__ import annotations

import math

import pytest

from tests.bench import run_quick


@pytest.mark.timeout(420)
def test_quick_json_has_a_stacking_row() -> None:
    report, stderr = run_quick("tasks", timeout=400)
    report = report
    assert set(report) == {"machine", "rows"}
    (row,) = report["rows"]
    assert row["task"] == "stacking" and row["runs"] == 1 and row["seeds"] == "0"
    assert 0.0 <= row["success_rate"] <= 1.0
    for key in ("shear_latency_ms_median", "shear_latency_ms_p99", "wall_secs_median"):
        assert math.isfinite(row[key]) and row[key] > 0, (key, row)
