"""The runtime with real processes and sockets, through the real launcher."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from tests.runtime.conftest import (
    GraphRun,
    alive,
    children_of,
    nodes_of,
    sink,
    still_alive,
    table_row,
)

FUZZER = "tests.runtime.nodes_for_tests:Fuzzer"


def wait_for_line(proc, text: str, timeout: float = 60) -> list[str]:
    """Read the launcher's output until a line contains ``text``."""
    lines = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"{text!r} not seen; output:\n{''.join(lines)}")


@pytest.mark.parametrize("host", [None, "127.0.0.1"], ids=["ipc", "tcp"])
def test_two_node_graph_delivers_every_message_in_order(
    graph_run: GraphRun, tmp_path: Path, host: str | None
) -> None:
    out = tmp_path / "sink.jsonl"
    source = {"impl": "synthetic.source", "params": {"rate_hz": 400, "count": 300}}
    if host:
        source["host"] = host
    graph = graph_run.write(
        {
            "src": source,
            "sink": sink(out, "src/tick"),
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    rows = graph_run.rows(out)
    assert [r["value"] for r in rows] == [float(i) for i in range(300)]
    assert [r["seq"] for r in rows] == list(range(300))
    assert "src/tick" in log and "restarts" in log  # the end-of-run table


def test_fan_in_keeps_each_source_in_order(graph_run: GraphRun, tmp_path: Path) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "a": {"impl": "synthetic.source", "params": {"rate_hz": 300, "count": 150}},
            "b": {
                "impl": "synthetic.source",
                "params": {"rate_hz": 200, "count": 100, "stop_when_done": False},
            },
            "relay": {
                "impl": "synthetic.relay",
                "params": {"add": 10000},
                "inputs": {"tick": "b/tick"},
            },
            "merge": {"impl": "synthetic.merge", "inputs": {"a": "a/tick", "b": "relay/tick"}},
            "sink": sink(out, "merge/tick"),
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    values = [r["value"] for r in graph_run.rows(out)]
    from_a = [v for v in values if v < 10000]
    from_b = [v - 10000 for v in values if v >= 10000]
    assert from_a == [float(i) for i in range(150)]
    assert from_b == [float(i) for i in range(100)]


def test_latest_policy_never_works_through_a_backlog(graph_run: GraphRun, tmp_path: Path) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 500, "count": 400}},
            "sink": {
                "impl": "synthetic.sink",
                "params": {"out_path": str(out), "work_secs": 0.05},
                "inputs": {"tick": {"from": "src/tick", "policy": "latest"}},
            },
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    values = [r["value"] for r in graph_run.rows(out)]
    # 400 ticks in 0.8 s against 50 ms a message: a backlog would deliver all 400.
    assert len(values) < 100
    assert values == sorted(values) and len(set(values)) == len(values)
    assert values[-1] == 399.0  # the newest one is always the one handled
    row = table_row(log, "src/tick -> sink.tick")
    assert row["superseded"] > 0
    assert row["dropped"] == 0  # skipped on purpose is not "dropped"
    assert row["delivered"] == len(values)


def test_killed_node_restarts_by_policy(graph_run: GraphRun, tmp_path: Path) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 100, "count": 800}},
            "relay": {
                "impl": "synthetic.relay",
                "params": {"crash_after": 20, "crash_marker": str(tmp_path / "crashed")},
                "inputs": {"tick": "src/tick"},
                "restart": {"policy": "on-failure", "max_restarts": 2, "backoff_secs": 0.1},
            },
            "sink": sink(out, "relay/tick"),
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    assert "node 'relay' failed (exit code 3); restart 1/2" in log
    assert "node 'relay' is back" in log
    values = [r["value"] for r in graph_run.rows(out)]
    # The restarted relay carried on (start-up under load may take a few seconds).
    assert values[-1] == 799.0
    assert values == sorted(values)


def test_required_node_failure_stops_graph_with_its_last_lines(
    graph_run: GraphRun, tmp_path: Path
) -> None:
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 100, "count": 10000}},
            "relay": {
                "impl": "synthetic.relay",
                "params": {"crash_after": 5},
                "inputs": {"tick": "src/tick"},
            },
            "sink": {"impl": "synthetic.sink", "inputs": {"tick": "relay/tick"}},
        }
    )
    code, log = graph_run.run(graph)
    assert code == 1
    assert "required node 'relay' failed (exit code 3); stopping the graph" in log


def test_ctrl_c_leaves_no_process_behind(graph_run: GraphRun) -> None:
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 50, "count": 100000}},
            "sink": {"impl": "synthetic.sink", "inputs": {"tick": "src/tick"}},
        }
    )
    proc = graph_run.start(graph)
    wait_for_line(proc, "all nodes ready")
    kids = children_of(proc.pid)
    assert len(nodes_of(proc.pid)) == 2 and all(alive(k) for k in kids)
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 130, out  # 128 + SIGINT, as a shell reports Ctrl-C
    assert "stopping: signal SIGINT" in out
    assert not any(alive(k) for k in kids)


def test_sigkill_of_launcher_takes_children_down(graph_run: GraphRun) -> None:
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 50, "count": 100000}},
            "sink": {"impl": "synthetic.sink", "inputs": {"tick": "src/tick"}},
        }
    )
    proc = graph_run.start(graph)
    wait_for_line(proc, "all nodes ready")
    kids = children_of(proc.pid)
    assert len(nodes_of(proc.pid)) == 2
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    assert still_alive(kids) == []


def test_hung_node_is_killed_and_restarted(graph_run: GraphRun, tmp_path: Path) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "src": {"impl": "synthetic.source", "params": {"rate_hz": 20, "count": 60}},
            "relay": {
                "impl": "synthetic.relay",
                "params": {"work_secs": 0.0},
                "inputs": {"tick": "src/tick"},
            },
            "slow": {
                "impl": "synthetic.sink",
                "params": {"work_secs": 4.0},
                "inputs": {"tick": "relay/tick"},
                "hang_timeout_secs": 1.0,
                "required": False,
                "restart": {"policy": "on-failure", "max_restarts": 1, "backoff_secs": 0.1},
            },
            "sink": sink(out, "relay/tick"),
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    assert "node 'slow' busy in one handler" in log
    assert "restart 1/1" in log
    # The rest of the graph did not wait for the hung node.
    assert graph_run.rows(out)[-1]["value"] == 59.0


def test_node_survives_garbage_frames_and_counts_them(graph_run: GraphRun, tmp_path: Path) -> None:
    out = tmp_path / "sink.jsonl"
    graph = graph_run.write(
        {
            "fuzz": {"impl": FUZZER, "params": {"count": 60, "seed": 3}},
            "sink": sink(out, "fuzz/tick"),
        }
    )
    code, log = graph_run.run(graph)
    assert code == 0, log
    # A mutation may still decode (a flipped bit in a float is a valid frame): those
    # carry negative values; every genuine tick must arrive, in order.
    values = [r["value"] for r in graph_run.rows(out) if r["value"] >= 0]
    assert values == [float(i) for i in range(60)]
    assert (
        table_row(log, "fuzz/tick -> sink.tick")["bad"] >= 50
    )  # most garbage frames were counted as bad
    assert "sink" in log and "bad frame" in log
