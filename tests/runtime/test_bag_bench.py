"""Smoke test of bench/bags.py's recording part (tiny sizes, no timing asserted)."""

from __future__ import annotations

from pathlib import Path

from bench.bags import Sizes, run_record
from runtime.bag import BagReader


def test_record_rows_and_bags(tmp_path: Path) -> None:
    rows = run_record(Sizes(frames_per_camera=3, repeats=1, live_secs=0.1, zstd=True), tmp_path)
    modes = [r["mode"] for r in rows]
    assert modes == [
        "record_bag",
        "record_raw_mcap",
        "record_bag_zstd",
        "record_raw_mcap_zstd",
        "read",
        "read_raw_mcap",
    ]
    for row in rows:
        assert row["frames"] == 6
        assert row["frames_per_sec"] > 0 and row["mb_per_sec"] > 0
    with BagReader(tmp_path / "cameras.mcap") as reader:
        stats = reader.stats()
    assert {t: s.messages for t, s in stats.items()} == {
        "left_camera/image": 3,
        "right_camera/image": 3,
    }
