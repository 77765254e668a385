"""``launch.py topic list|hz|echo|nodes`` against a running graph, checked against the
graph's own end-of-run table."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest

import launch
from runtime.introspect import Rate
from runtime.status import find_runs
from tests.runtime.conftest import GraphRun, sink, table_row

RATE_HZ = 40.0
COUNT = 400  # 10 s at 40 Hz: time to look


def wait_for_run(pid: int, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(r.status.get("pid") == pid for r in find_runs()):
            return
        time.sleep(0.2)
    raise AssertionError(f"launcher {pid} wrote no status within {timeout} s")


def echoed_seqs(out: str) -> list[int]:
    """The seq of each message ``topic echo`` printed; checks what it printed of each."""
    lines = out.splitlines()
    heads = [line for line in lines if line.startswith("--- src/tick #")]
    assert heads and all(" Tick seq " in h for h in heads), out
    assert sum(line.startswith("value: ") for line in lines) == len(heads)
    assert sum(line.startswith("header: {'stamp_nanos': ") for line in lines) == len(heads)
    return [int(h.split(" seq ")[1].split()[0]) for h in heads]


def test_topic_tools_against_a_running_graph(
    graph_run: GraphRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": RATE_HZ, "count": COUNT}},
            "sink": sink(out, "src/tick"),
        },
        name=f"ticks_{os.getpid()}.yaml",  # a name no other run on this machine has
    )
    proc = graph_run.start(graph)
    try:
        wait_for_run(proc.pid)
        time.sleep(1.5)  # a second of messages, counted by a heartbeat
        run = str(proc.pid)
        assert launch.main(["topic", "list", "--run", run]) == 0
        listed = capsys.readouterr().out
        row = next(line for line in listed.splitlines() if line.startswith("src/tick"))
        cells = row.split()
        assert cells[1] == "Tick" and row.endswith("src -> sink.tick")
        listed_rate = float(cells[2])

        by_name = ["topic", "nodes", "--run", f"ticks_{os.getpid()}"]  # the graph's name
        assert launch.main(by_name) == 0
        nodes = capsys.readouterr().out
        assert re.search(r"^src\s+running\s+0\s", nodes, re.M), nodes
        assert re.search(r"^sink\s+running\s+0\s", nodes, re.M), nodes

        assert launch.main(["topic", "hz", "src/tick", "--run", run, "--secs", "3"]) == 0
        last = capsys.readouterr().out.strip().splitlines()[-1]
        hz_rate = float(re.search(r"rate ([\d.]+) Hz", last).group(1))  # type: ignore[union-attr]

        every = ["topic", "echo", "src/tick", "--run", run, "--limit", "3", "--every"]
        assert launch.main(every) == 0
        seqs = echoed_seqs(capsys.readouterr().out)
        assert seqs == list(range(seqs[0], seqs[0] + 3))  # every message, in order
        sampled = ["topic", "echo", "src/tick", "--run", run, "--limit", "3", "--max-hz", "4"]
        assert launch.main(sampled) == 0
        seqs = echoed_seqs(capsys.readouterr().out)
        assert all(b - a >= 3 for a, b in zip(seqs, seqs[1:], strict=False)), seqs  # 40/4 Hz
        log, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, log
    final = table_row(log, "src/tick -> sink.tick")["rate_hz"]
    assert hz_rate == pytest.approx(final, rel=0.15), (hz_rate, final)
    assert listed_rate == pytest.approx(final, rel=0.25), (listed_rate, final)
    # The taps took nothing from the graph: the sink got every tick.
    assert len(graph_run.rows(out)) == COUNT


def test_topic_names_what_is_running_when_it_cannot_choose(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert launch.main(["topic", "list", "--run", "no_such_graph"]) == 2
    assert "no running graph named 'no_such_graph'" in capsys.readouterr().err


def test_rate_of_regular_arrivals() -> None:
    rate = Rate(window=10)
    assert rate.summary() is None
    for i in range(50):
        rate.add(i * 0.1)
    summary = rate.summary()
    assert summary is not None
    assert summary["rate_hz"] == pytest.approx(10.0)
    assert summary["periods"] == 10 and summary["std_secs"] == pytest.approx(0.0, abs=1e-12)
