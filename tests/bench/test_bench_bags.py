"""Smoke test of ``python -m bench.bags --quick``: it runs, and its JSON has every row.

No timing is asserted: the figures only have to exist, be finite and be positive.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MODES = {
    "record_bag",
    "record_raw_mcap",
    "read",
    "read_raw_mcap",
    "record_live",
    "record_pipeline",
    *(
        f"replay_{pace}{fan}{work}"
        for pace in ("fast", "lockstep")
        for fan in ("", "_fanin")
        for work in ("", "_work10ms")
    ),
}


@pytest.mark.timeout(900)
def test_quick_json_has_every_mode_with_finite_positive_figures() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.bags", "--quick", "--json", "--no-plot"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=880,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout)
    assert set(report) == {"machine", "rows"}
    rows = {row["mode"]: row for row in report["rows"]}
    assert set(rows) == MODES
    for mode, row in rows.items():
        for key in ("frames_per_sec", "mb_per_sec"):
            assert math.isfinite(row[key]) and row[key] > 0, (mode, key)
    assert rows["read"]["frames"] == rows["read_raw_mcap"]["frames"] == 180
