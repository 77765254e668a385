"""Smoke test of ``bench/codec.py``: every message, operation and input gets a row.

No timing is asserted; the run itself checks that every array layout encodes to the
same bytes (it raises otherwise).
"""

from __future__ import annotations

import math

from bench.codec import run


def test_quick_rows_cover_every_case_with_finite_positive_times() -> None:
    rows = run(quick=True)
    cases = {(r["message"], r["op"], r["input"]) for r in rows}
    assert ("ToFImage", "encode", "big_endian") in cases
    assert ("ToFImage", "decode", "zmq.Frame") in cases
    assert len(cases) == len(rows) == 13  # ToFImage 5, PoseEstimate 5, Pressure 3
    for row in rows:
        assert math.isfinite(row["us_best"]) and row["us_best"] > 0
        assert row["us_median"] >= row["us_best"]
        assert row["frame_bytes"] > 0
