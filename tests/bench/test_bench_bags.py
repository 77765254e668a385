"""Smoke test of ``python -m bench.bags --quick``: it runs, and its JSON has every row.

No timing is asserted: the figures only have to exist, be finite and be positive.
"""

from __future__ import annotations

import math

import pytest

from tests.bench import run_quick

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
    report, stderr = run_quick("bags", "--no-plot", timeout=880)
    report = report
    assert set(report) == {"machine", "rows"}
    rows = {row["mode"]: row for row in report["rows"]}
    assert set(rows) == MODES
    for mode, row in rows.items():
        for key in ("frames_per_sec", "mb_per_sec"):
            assert math.isfinite(row[key]) and row[key] > 0, (mode, key)
    assert rows["read"]["frames"] == rows["read_raw_mcap"]["frames"] == 180
