"""The paper's three tasks end to end: real processes, short scenes (see docs/tasks.md)."""

from __future__ import annotations

import json
import re

from nodes.supervisor.sort import DEFAULT_BINS
from tests.test_graphs import launch


def events(out: str, task: str, event: str) -> list[str]:
    """The details of a task's events in the launcher's output (its log lines)."""
    pattern = re.compile(rf"\] INFO {task}: {event} (.*)$")
    return [m.group(1) for line in out.splitlines() if (m := pattern.search(line))]


def test_dish_loading_routes_every_object_right() -> None:
    proc = launch(
        "graphs/dish_loading.yaml", "--set", "supervisor.objects=4", "--set", "supervisor.seed=0"
    )
    assert proc.returncode == 0, proc.stdout[-3000:]
    objects = [json.loads(d) for d in events(proc.stdout, "dish_loading", "object")]
    assert {o["true_class"] for o in objects} == {
        "mug",
        "pet_bottle",
        "square_bottle",
        "wine_glass",
    }
    assert all(o["right"] for o in objects), objects
    (summary,) = [json.loads(d) for d in events(proc.stdout, "dish_loading", "summary")]
    assert summary["objects"] == 4 and summary["wrong"] == 0


def test_dish_loading_fails_when_an_object_goes_to_a_wrong_bin() -> None:
    # Bins swapped against the judge's table: the classifier is right, the routing
    # wrong; the verdict says so.
    bins = '[["mug", "recycling"], ["wine_glass", "recycling"], ["pet_bottle", "dishwasher"], ["square_bottle", "dishwasher"]]'
    proc = launch(
        "graphs/dish_loading.yaml",
        "--set",
        "supervisor.objects=1",
        "--set",
        f"supervisor.bins={bins}",
        "--set",
        f"supervisor.truth_bins={json.dumps([list(b) for b in DEFAULT_BINS])}",
    )
    assert proc.returncode == 1, proc.stdout[-3000:]
    assert "1 wrong" in proc.stdout and "reports failure (exit code 1)" in proc.stdout
