"""Smoke test of ``python -m bench.introspection``: it runs, the echo clients attached,
and its JSON has the promised shape (no timing is asserted)."""

from __future__ import annotations

import math

import pytest

from tests.bench import run_quick


@pytest.mark.timeout(300)
def test_quick_json_compares_the_graph_alone_and_with_echo_clients() -> None:
    report, _ = run_quick("introspection", timeout=280)
    rows = {row["setup"]: row for row in report["rows"]}
    assert set(rows) == {"alone", "echo", "echo_every"}
    assert rows["alone"]["throughput_vs_alone"] == 1.0
    for row in rows.values():
        assert math.isfinite(row["frames_per_sec"]) and row["frames_per_sec"] > 0
        assert row["throughput_vs_alone"] > 0
    assert rows["echo"]["echo_clients"] == 3
    assert rows["echo"]["echoed_frames_min"] > 0  # each client printed frames
    assert rows["echo_every"]["echoed_frames_min"] > 0
