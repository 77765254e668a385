"""``python -m bench.shear --quick`` and ``python -m bench.classifier --quick`` run, print
their rows and write their plots (the pose bench's smoke test is in test_bench_pose)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]


@pytest.mark.parametrize("name", ["shear", "classifier"])
def test_quick_run_prints_rows_and_writes_the_plot(name: str, tmp_path: Path) -> None:
    png = tmp_path / f"{name}.png"
    done = subprocess.run(
        [sys.executable, "-m", f"bench.{name}", "--quick", "--json", "--plot", str(png)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = json.loads(done.stdout)["rows"]
    assert rows and png.stat().st_size > 10_000
    assert f"[bench.{name}] 1/" in done.stderr  # one progress line per sweep point
    if name == "shear":
        for row in rows:
            assert math.isfinite(row["dir_err_deg_median"]) and row["ms_per_frame_median"] > 0
    else:
        assert all(0.0 <= r["accuracy"] <= 1.0 and r["infer_ms_median"] > 0 for r in rows)
