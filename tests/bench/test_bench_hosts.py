"""Smoke test of ``python -m bench.hosts --quick``: it runs, and its JSON has both rows.

No timing is asserted: the figures only have to exist, be finite and be positive.
"""

from __future__ import annotations

import math

from tests.bench import run_quick


def test_quick_json_has_both_modes_with_finite_positive_figures() -> None:
    report, stderr = run_quick("hosts", timeout=300)
    rows = {r["mode"]: r for r in report["rows"]}
    assert set(rows) == {"one_host", "two_hosts"}
    for row in rows.values():
        assert row["messages"] == 200  # every message of the bag, through the merge
        assert math.isfinite(row["msgs_per_sec"]) and row["msgs_per_sec"] > 0
        assert math.isfinite(row["vs_one_host"]) and row["vs_one_host"] > 0
    assert rows["one_host"]["vs_one_host"] == 1.0
    assert "[bench.hosts] 2/2" in stderr  # a progress line per point
