"""Smoke test of ``bench/startup.py``: every row measured, the stops exit with 130.

No timing goal is asserted (the machine running the tests is loaded); the run itself
raises if a command fails or a SIGINT does not end the launcher with 130.
"""

from __future__ import annotations

import math

import pytest

from bench.startup import run


def test_quick_rows_cover_start_and_stop() -> None:
    rows = run(quick=True)
    assert [r["what"] for r in rows] == [
        "--help",
        "bag info",
        "--check graph.yaml --only world,gripper",
        "graph.yaml --only world,gripper ready",
        "graph.yaml --only world,gripper ready, SBG_NODE_START=spawn",
        "ctrl-c while running",
        "ctrl-c while starting",
    ]
    for row in rows:
        assert row["runs"] == 1
        assert math.isfinite(row["median_s"]) and row["median_s"] > 0
    compared = [r for r in rows if math.isfinite(r["vs_fork"])]
    assert [r["what"] for r in compared] == [r["what"] for r in rows[3:5]]
    fork, spawn = compared
    # The forked start is the baseline; the spawned one's ratio is of the two medians
    # measured side by side (no goal on it: the machine running the tests is loaded).
    assert fork["what"].endswith("ready") and fork["vs_fork"] == 1.0
    assert spawn["vs_fork"] == pytest.approx(spawn["median_s"] / fork["median_s"], rel=1e-12)
    assert spawn["median_s"] != fork["median_s"]  # two measurements, not one row twice
