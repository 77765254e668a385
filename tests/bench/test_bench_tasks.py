"""Smoke test of ``python -m bench.tasks``: one stacking scene runs and the JSON has the
promised shape (task, success rate, latencies). No figure is judged beyond being there.
The handover's release latency is computed right on made-up topics."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tests.bench import run_quick


@pytest.mark.timeout(420)
def test_quick_json_has_a_stacking_row() -> None:
    report, stderr = run_quick("tasks", timeout=400)
    report = report
    assert set(report) == {"machine", "rows"}
    (row,) = report["rows"]
    assert row["task"] == "stacking" and row["runs"] == 1 and row["seeds"] == "0"
    assert 0.0 <= row["success_rate"] <= 1.0
    for key in ("shear_latency_ms_median", "shear_latency_ms_p99", "wall_secs_median"):
        assert math.isfinite(row[key]) and row[key] > 0, (key, row)


def test_the_handover_latency_runs_from_the_pull_or_the_stable_grasp_if_later() -> None:
    # The bench once drew pulls that began before the grasp was stable (seed 1: 0.3 s
    # before): the wait for the stable grasp counted as release latency.
    from bench.tasks import pull_start_secs, release_latency

    ms = 1_000_000
    moved = np.eye(4)
    moved[2, 3] = 0.001
    # Frames every 33 ms, received 5 ms after their instant; the pull moves the object
    # from frame 10 on.
    truth = [
        (
            k * 33 * ms,
            k * 33 * ms + 5 * ms,
            SimpleNamespace(tool_from_object=moved if k >= 10 else np.eye(4)),
        )
        for k in range(30)
    ]

    def event(name: str, k: int, after_ms: float) -> tuple[int, int, SimpleNamespace]:
        return (k * 33 * ms, int((k * 33 + after_ms) * ms), SimpleNamespace(event=name))

    topics: dict[str, list] = {"world/ground_truth": truth, "world/state": truth}
    topics["supervisor/event"] = [event("stable", 5, 1), event("release", 14, 60)]
    secs, graph_ms = release_latency(topics)
    assert secs == pytest.approx(4 * 0.033) and graph_ms == [pytest.approx(4 * 33 + 60 - 5)]
    topics["supervisor/event"] = [event("stable", 12, 1), event("release", 14, 60)]
    secs, graph_ms = release_latency(topics)
    assert secs == pytest.approx(2 * 0.033) and graph_ms == [pytest.approx(2 * 33 + 60 - 5)]
    topics["supervisor/event"] = [event("stable", 5, 1)]
    assert release_latency(topics) == (None, [])
    # The drawn pulls start after the default scene's stable grasp (about 1.7 s).
    assert min(pull_start_secs(seed) for seed in range(20)) > 1.9
