"""Smoke tests of ``python -m bench.transport``, ``bench.transport_steps`` and
``bench.transport_source``: they run, and their JSON has the promised shape.

No timing is asserted: the figures only have to exist, be finite and be positive.
"""

from __future__ import annotations

import math

import pytest

from bench.nodes import THREAD_GROUPS
from tests.bench import run_quick

FIGURES = (
    "frames_per_sec",
    "throughput_vs_raw",
    "latency_ms_median",
    "latency_ms_p99",
    "latency_vs_raw",
    "source_cpu_us_per_frame",
    "sink_cpu_us_per_frame",
)


@pytest.mark.timeout(240)
def test_quick_json_has_every_transport_and_impl_with_finite_positive_figures() -> None:
    report, stderr = run_quick("transport", "--no-plot", timeout=220)
    report = report
    assert set(report) == {"machine", "rows"}
    rows = report["rows"]
    keys = {(row["transport"], row["impl"]) for row in rows}
    assert keys == {
        (t, i) for t in ("ipc", "tcp") for i in ("runtime", "codec", "raw", "raw_parts")
    } | {("netns_tcp", "raw_parts"), ("netns_curve", "raw_parts")}
    assert len(rows) == len(keys)
    across = [row for row in rows if row["transport"].startswith("netns")]
    rows = [row for row in rows if row not in across]
    if any("skipped" in row for row in across):  # no namespaces here: both say why
        assert all(row["skipped"] for row in across)
    else:
        for row in across:
            for name in ("frames_per_sec", "latency_ms_median", "throughput_vs_plain"):
                assert math.isfinite(row[name]) and row[name] > 0, (row["transport"], name)
            assert row["latency_ms_p99"] >= row["latency_ms_median"]
        assert across[0]["throughput_vs_plain"] == 1.0  # the plain row is the reference
    for row in rows:
        for name in FIGURES:
            value = row[name]
            assert isinstance(value, int | float), (row["transport"], row["impl"], name, value)
            assert math.isfinite(value) and value > 0, (row["transport"], row["impl"], name, value)
        assert row["drops"] >= 0
        assert row["latency_ms_p99"] >= row["latency_ms_median"]
        for side in ("source", "sink"):
            # Each side's CPU by thread: the loop's thread works, and the three add up to
            # about the process CPU of the same window (both are medians over repeats).
            split = [row[f"{side}_{group}_us_per_frame"] for group in THREAD_GROUPS]
            assert all(math.isfinite(v) and v >= 0 for v in split), (row["impl"], side, split)
            assert split[0] > 0
            total = row[f"{side}_cpu_us_per_frame"]
            assert 0.5 * total <= sum(split) <= 1.5 * total, (row["impl"], side, split, total)
        if row["impl"] == "raw":
            assert row["throughput_vs_raw"] == 1.0


@pytest.mark.timeout(120)
def test_steps_quick_json_has_every_step_of_both_sides() -> None:
    from bench.transport_steps import SINK_STEPS, SOURCE_STEPS

    report, _ = run_quick("transport_steps", timeout=100)
    rows = report["rows"]
    assert [(row["side"], row["step"]) for row in rows] == [
        *(("source", step) for step in SOURCE_STEPS),
        *(("sink", step) for step in SINK_STEPS),
    ]
    for row in rows:
        mine = row["runtime_us"]
        assert math.isfinite(mine) and mine > 0, row
        if row["step"] in ("encode", "finite"):  # the raw pair has no such step
            assert "raw_us" not in row and row["extra_us"] == mine
        else:
            assert math.isfinite(row["raw_us"]) and row["raw_us"] > 0, row
            assert row["extra_us"] == pytest.approx(mine - row["raw_us"])
            assert row["vs_raw"] == pytest.approx(mine / row["raw_us"])


@pytest.mark.timeout(120)
def test_source_quick_json_has_every_variant_paired_with_publish() -> None:
    from bench.transport_source import VARIANTS

    report, _ = run_quick("transport_source", timeout=100)
    rows = report["rows"]
    assert [row["variant"] for row in rows] == list(VARIANTS)
    for row in rows:
        for name in ("main_us_per_frame", "process_us_per_frame"):
            assert math.isfinite(row[name]) and row[name] > 0, row
        assert row["main_extra_us_q1"] <= row["main_extra_us"] <= row["main_extra_us_q3"], row
        assert row["sink_dropped"] == 0
    assert rows[0]["main_extra_us"] == rows[0]["process_extra_us"] == 0  # publish itself
