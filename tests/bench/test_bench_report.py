"""``python -m bench.report``: sweeps found, run in their own process, one page written."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bench import report
from bench.heldout import HeldOut, wilson_interval
from bench.report_page import markdown_table, pareto_front, render

ROOT = Path(__file__).resolve().parents[2]


def test_discover_finds_every_sweep_in_order() -> None:
    found = report.discover()
    assert found[: len(report.ORDER)] == list(report.ORDER)
    assert found[:3] == ["transport", "hosts", "codec"]
    assert not set(found) & report.NOT_SWEEPS


def test_quick_report_writes_a_page(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "performance.md"
    argv = ["--quick", "--only", "codec", "--heldout-grasps", "0", "--out", str(out)]
    assert report.main(argv) == 0
    progress = capsys.readouterr().out
    assert "[1/1] bench.codec:" in progress and "rows" in progress
    page = out.read_text()
    assert page.startswith("# Performance")
    assert "## Machine" in page and "cpu_count" in page
    assert "## codec" in page and "python -m bench.codec --quick" in page
    assert "| ToFImage |" in page
    assert "Not measured in this run" in page


def test_unknown_sweep_is_an_error() -> None:
    with pytest.raises(SystemExit):
        report.main(["--only", "no_such_sweep"])


def test_page_plots_error_against_time_and_finds_the_defaults(tmp_path: Path) -> None:
    shear = [
        {
            "method": "farneback",
            "setting": s,
            "scale": sc,
            "warm_start": w,
            "ms_per_frame_median": t,
            "dir_err_deg_median": e,
        }
        for s, sc, w, t, e in [
            ("fb", 1.0, False, 16.0, 0.3),
            ("warm half fb", 0.5, True, 6.5, 0.46),
            ("slow and bad", 1.0, False, 30.0, 0.9),
        ]
    ]
    sim_rows = [
        {
            "sweep": "membrane",
            "resolution_divisor": d,
            "march_steps": m,
            "ms_per_frame": 40.0 / d * m,
            "depth_rms_mm": 0.1 * d / m,
        }
        for d in (1, 2, 4)
        for m in (1, 3)
    ] + [
        {"sweep": "effects", "effects": e, "ms_per_frame": t}
        for e, t in [("+ir", 8.0), ("+shear", 18.0)]
    ]
    toy = [
        {
            "data": "toy",
            "modality": m,
            "input_px": 32,
            "width": 0.125,
            "accuracy": a,
            "infer_ms_median": t,
        }
        for m, a, t in [("depth", 0.9, 1.0), ("both", 0.95, 2.0)]
    ]
    sweeps = [
        report.Sweep(name="classifier", command="python -m bench.classifier", rows=toy),
        report.Sweep(name="shear", command="python -m bench.shear", rows=shear, secs=1.0),
        report.Sweep(name="sim", command="python -m bench.sim", rows=sim_rows, secs=1.0),
        report.Sweep(name="bags", command="python -m bench.bags", error="exit code 1: boom"),
    ]
    accuracy = HeldOut(
        grasps=200,
        correct=199,
        frames=1200,
        frame_accuracy=0.99,
        classes=["mug", "pet_bottle"],
        make_command="python launch.py x",
        score_command="python -m perception.classify evaluate m d",
        secs=60.0,
    )
    out = tmp_path / "docs" / "performance.md"
    page = render(
        sweeps, accuracy, machine={"cpu_count": 2}, quick=False, total_secs=90.0, out=out, root=ROOT
    )
    for name in ("shear", "sim"):
        assert (out.parent / "img" / "performance" / f"{name}_pareto.png").stat().st_size > 1000
        assert f"(img/performance/{name}_pareto.png)" in page
    assert "warm half fb: 6.5 ms_per_frame_median, 0.46 dir_err_deg_median (on the front)" in page
    assert "slow and bad" not in page.split("Pareto front")[1].split("\n")[0]
    assert "resolution_divisor = 4, march_steps = 3" in page
    assert (out.parent / "img" / "performance" / "sim_effects.png").is_file()
    assert "(img/performance/sim_effects.png)" in page
    assert "This sweep failed in this run: exit code 1: boom" in page
    assert "toy dataset" in page
    assert "**99.50%**" in page and "200 grasps" in page
    # Toy accuracies mean nothing: no plot or front beside the held-out headline.
    classifier = page.split("## classifier")[1].split("\n## ")[0]
    assert "classifier_pareto.png" not in page and "Pareto front" not in classifier
    assert not (out.parent / "img" / "performance" / "classifier_pareto.png").exists()


def test_classifier_on_real_data_gets_its_plot(tmp_path: Path) -> None:
    rows = [
        {
            "data": "autolabel",
            "modality": m,
            "input_px": 64,
            "width": 0.25,
            "accuracy": a,
            "infer_ms_median": t,
        }
        for m, a, t in [("depth", 0.9, 1.0), ("both", 0.97, 2.0)]
    ]
    out = tmp_path / "docs" / "performance.md"
    sweeps = [report.Sweep(name="classifier", command="python -m bench.classifier", rows=rows)]
    page = render(
        sweeps, None, machine={"cpu_count": 2}, quick=False, total_secs=9.0, out=out, root=ROOT
    )
    assert (out.parent / "img" / "performance" / "classifier_pareto.png").stat().st_size > 1000
    assert "toy dataset" not in page and "Pareto front" in page


def test_pareto_front_skips_dominated_and_nan_points() -> None:
    points = [(1.0, 5.0), (2.0, 1.0), (3.0, 3.0), (math.nan, 0.0), (2.0, 1.0)]
    assert pareto_front(points) == [0, 1, 4]


def test_markdown_table_escapes_bars_and_rounds() -> None:
    table = markdown_table([{"a": "x|y", "b": 1.234567}])
    assert table.splitlines()[2] == "| x/y | 1.235 |"


def test_wilson_interval() -> None:
    lo, hi = wilson_interval(199, 200)
    assert 0.97 < lo < 0.98 and 0.999 < hi <= 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and 0.25 < hi < 0.35
    with pytest.raises(ValueError, match="correct"):
        wilson_interval(11, 10)
