"""``python -m bench.shear --quick`` and ``python -m bench.classifier --quick`` run, print
their rows and write their plots (the pose bench's smoke test is in test_bench_pose)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tests.bench import run_quick


@pytest.mark.parametrize("name", ["shear", "classifier"])
def test_quick_run_prints_rows_and_writes_the_plot(name: str, tmp_path: Path) -> None:
    png = tmp_path / f"{name}.png"
    report, stderr = run_quick(name, "--plot", str(png), timeout=600)
    rows = report["rows"]
    assert rows and png.stat().st_size > 10_000
    assert f"[bench.{name}] 1/" in stderr  # one progress line per sweep point
    if name == "shear":
        for row in rows:
            assert math.isfinite(row["dir_err_deg_median"]) and row["ms_per_frame_median"] > 0
    else:
        assert all(0.0 <= r["accuracy"] <= 1.0 and r["infer_ms_median"] > 0 for r in rows)
