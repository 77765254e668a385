"""Smoke test of ``bench/batch.py``: every row measured, finite and positive, the ratios
against the plain loop and the lone process computed from them (no speed asserted: the
machine running the tests is shared)."""

from __future__ import annotations

import math

import pytest

from bench.batch import run


@pytest.mark.timeout(900)  # one recording, 3 replays, 3 worlds, 4 Ray starts, 2 trainings
def test_quick_rows_cover_replay_autolabel_and_training() -> None:
    rows = run(quick=True)
    kinds = [(r["work"], r["mode"], r["workers"]) for r in rows]
    assert kinds == [
        ("ray start", "ray", 1),
        ("replay", "loop", 1),
        ("replay", "ray", 1),
        ("replay", "ray", 2),
        ("autolabel", "loop", 1),
        ("autolabel", "ray", 1),
        ("autolabel", "ray", 2),
        ("train", "alone", 1),
        ("train", "torchrun", 2),
    ]
    for row in rows[1:7]:
        assert row["items"] >= 1 and math.isfinite(row["per_min"]) and row["per_min"] > 0
        loop = next(r for r in rows if r["work"] == row["work"] and r["mode"] == "loop")
        assert row["vs_loop"] == pytest.approx(row["per_min"] / loop["per_min"])
    for row in rows[7:]:
        assert math.isfinite(row["per_sec"]) and row["per_sec"] > 0
    assert rows[8]["vs_alone"] == pytest.approx(rows[8]["per_sec"] / rows[7]["per_sec"])
