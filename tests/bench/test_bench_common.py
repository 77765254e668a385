"""The shared benchmark helpers: progress lines and the launcher log."""

from __future__ import annotations

import io
import re

from bench.common import progress


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
