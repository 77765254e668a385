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
HZ_LINE = re.compile(
    r"rate (?P<rate>[\d.]+) Hz  min (?P<min>[\d.]+) s  max (?P<max>[\d.]+) s  .*"
    r"window (?P<periods>\d+)  \((?P<count>\d+) messages\)  "
    r"stamps (?P<stamp_rate>[\d.]+) Hz  seq (?P<first>\d+)-(?P<last>\d+)"
)


def wait_for_run(pid: int, topic: str, timeout: float = 60.0) -> None:
    """Until launcher ``pid``'s status counts a message on ``topic`` (a heartbeat's)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for r in find_runs():
            if r.status.get("pid") == pid and r.status["topics"][topic]["messages"] > 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"launcher {pid}'s status counted nothing on {topic} in {timeout} s")


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
        wait_for_run(proc.pid, "src/tick")
        run = str(proc.pid)
        assert launch.main(["topic", "list", "--run", run]) == 0
        listed = capsys.readouterr().out
        elapsed = float(re.search(r"running ([\d.]+) s", listed).group(1))  # type: ignore[union-attr]
        row = next(line for line in listed.splitlines() if line.startswith("src/tick"))
        cells = row.split()
        assert cells[1] == "Tick" and row.endswith("src -> sink.tick")
        listed_rate, listed_messages = float(cells[2]), int(cells[3])
        # The rate is the messages over the seconds running, both as printed (rounded).
        assert 0 < listed_messages <= COUNT, row
        low, high = listed_messages / (elapsed + 0.05), listed_messages / max(elapsed - 0.05, 1e-9)
        assert low - 0.05 <= listed_rate <= high + 0.05, (listed_rate, listed_messages, elapsed)

        by_name = ["topic", "nodes", "--run", f"ticks_{os.getpid()}"]  # the graph's name
        assert launch.main(by_name) == 0
        nodes = capsys.readouterr().out
        assert re.search(r"^src\s+running\s+0\s", nodes, re.M), nodes
        assert re.search(r"^sink\s+running\s+0\s", nodes, re.M), nodes

        assert launch.main(["topic", "hz", "src/tick", "--run", run, "--secs", "3"]) == 0
        last = capsys.readouterr().out.strip().splitlines()[-1]
        hz = HZ_LINE.search(last)
        assert hz is not None, last

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
    assert listed_messages <= table_row(log, "src/tick -> sink.tick")["messages"] == COUNT
    # The taps took nothing from the graph: the sink got every tick.
    rows = graph_run.rows(out)
    assert [r["seq"] for r in rows] == list(range(COUNT))
    # hz measured every message from its first seq to its last, and the rate their
    # stamps say is the one the sink's copies of the same messages say.
    periods, count, first, last_seq = (int(hz[k]) for k in ("periods", "count", "first", "last"))
    assert count == periods + 1 and last_seq - first == periods, last
    stamps = {r["seq"]: r["stamp_nanos"] for r in rows}
    said = periods / ((stamps[last_seq] - stamps[first]) / 1e9)
    assert float(hz["stamp_rate"]) == pytest.approx(said, abs=0.006), (last, said)
    # The arrival rate is the mean of the periods whose extremes it prints (4 decimals).
    assert float(hz["min"]) - 5e-5 <= 1 / float(hz["rate"]) <= float(hz["max"]) + 5e-5, last


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
