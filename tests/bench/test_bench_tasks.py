"""Smoke test of ``python -m bench.tasks``: one stacking scene runs and the JSON has the
promised shape (task, success rate, latencies). No figure is judged beyond being there."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(420)
def test_quick_json_has_a_stacking_row() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.tasks", "--quick", "--json"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout)
    assert set(report) == {"machine", "rows"}
    (row,) = report["rows"]
    assert row["task"] == "stacking" and row["runs"] == 1 and row["seeds"] == "0"
    assert 0.0 <= row["success_rate"] <= 1.0
    for key in ("shear_latency_ms_median", "shear_latency_ms_p99", "wall_secs_median"):
        assert math.isfinite(row[key]) and row[key] > 0, (key, row)
