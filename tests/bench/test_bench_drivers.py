"""Smoke test of ``bench/drivers.py``: every row present, figures finite. No timing asserted."""

from __future__ import annotations

import math

from bench.drivers import run


def test_quick_rows_cover_latency_stream_and_pressure() -> None:
    rows = run(quick=True)
    rtt = {r["command"]: r for r in rows if r["case"] == "wsg50_rtt"}
    assert set(rtt) == {"GET_OPENING", "SET_FORCE_LIMIT", "MOVE+STOP"}
    for row in rtt.values():
        assert math.isfinite(row["us_median"]) and row["us_median"] > 0
        assert row["us_p90"] >= row["us_median"] and row["vs_raw"] > 0
    streams = [r for r in rows if r["case"] == "wsg50_stream"]
    assert [r["requested_hz"] for r in streams] == [50.0, 100.0, 200.0]
    for row in streams:
        assert 0 < row["received_hz"] < 2 * row["requested_hz"]
    (pressure,) = [r for r in rows if r["case"] == "pressure_read"]
    assert pressure["reads_per_s"] > 0 and pressure["calls"] == 200
