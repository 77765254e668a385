"""The shared benchmark helpers: progress lines and the launcher log."""

from __future__ import annotations

import io
import re

from bench.common import label_points, progress


def test_progress_prints_one_line_per_point_with_the_time_left() -> None:
    out = io.StringIO()
    seen = list(progress(["a", "b", "c"], "bench.x", label=str.upper, stream=out))
    assert seen == ["a", "b", "c"]
    lines = out.getvalue().splitlines()
    assert len(lines) == 3
    for i, (line, name) in enumerate(zip(lines, "ABC", strict=True), 1):
        assert re.fullmatch(
            rf"\[bench\.x\] {i}/3 {name}: \d+\.\d s; \d+ s so far, about \d+ s left", line
        ), line
    assert lines[-1].endswith("about 0 s left")


def test_progress_of_an_empty_sweep_prints_nothing() -> None:
    out = io.StringIO()
    assert list(progress([], "bench.x", stream=out)) == []
    assert out.getvalue() == ""


def test_point_labels_do_not_overlap_where_points_cluster() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3))
    # Two points on top of each other, two close neighbours, and one alone.
    points = [(3.2, 0.78), (3.3, 0.78), (3.9, 0.78), (4.3, 0.98), (4.8, 0.98), (20.0, 2.0)]
    ax.scatter(*zip(*points, strict=True))
    ax.set_xscale("log")
    fig.tight_layout()
    labels = [str(i) for i in range(11, 11 + len(points))]
    label_points(ax, points, labels)
    renderer = fig.canvas.get_renderer()
    boxes = [text.get_window_extent(renderer) for text in ax.texts]
    assert [text.get_text() for text in ax.texts] == labels
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not a.overlaps(b), (a, b)
    plt.close(fig)
