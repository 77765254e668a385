"""Supervision of real node processes: restarts, frozen nodes, honest end-of-run counts."""

from __future__ import annotations

import io
import os
import signal
import threading
import time
from pathlib import Path

import pytest

import nodes  # noqa: F401 - the registered implementations
from runtime import launcher as launcher_module
from runtime.graph import check
from runtime.launcher import Launcher
from tests.faults.conftest import FAULTS, sink, ticker
from tests.runtime.conftest import comm, still_alive, table_row


def launcher_for(nodes_doc: dict, **kwargs) -> tuple[Launcher, io.StringIO]:
    out = io.StringIO()
    return Launcher(check({"nodes": nodes_doc}), out=out, **kwargs), out


def when_running(launcher: Launcher, node: str, action, timeout: float = 60) -> threading.Thread:
    """Call ``action(pid)`` on a thread once ``node`` is running."""

    def wait() -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            proc = launcher.procs[node]
            if proc.state == "running" and proc.process is not None:
                action(proc.process.pid)
                return
            time.sleep(0.02)

    thread = threading.Thread(target=wait, daemon=True)
    thread.start()
    return thread


def test_restarted_node_gets_the_start_up_allowance(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The heartbeat rule is shortened to 1 s; the restarted node takes 3 s to build.
    monkeypatch.setattr(launcher_module, "HEARTBEAT_TIMEOUT_SECS", 1.0)
    a = ticker(crash_after=5, crash_marker=str(tmp_path / "crashed"), restarted_init_secs=3.0)
    a["restart"] = {"policy": "on-failure", "max_restarts": 1, "backoff_secs": 0.1}
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=8.0)
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    assert "node 'a' failed (exit code 3); restart 1/1" in log
    assert "sent no heartbeat" not in log
    assert "node 'a' is back" in log


def test_frozen_node_is_killed_by_the_heartbeat_rule_and_restarted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(launcher_module, "HEARTBEAT_TIMEOUT_SECS", 1.0)
    a = ticker()
    a["restart"] = {"policy": "on-failure", "max_restarts": 1, "backoff_secs": 0.1}
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=6.0)
    when_running(launcher, "a", lambda pid: os.kill(pid, signal.SIGSTOP))
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    assert "node 'a' sent no heartbeat for 1 s; killed" in log
    assert "node 'a' is back" in log


def test_corrupted_seqs_and_bad_frames_are_not_counted_as_dropped() -> None:
    launcher, out = launcher_for(
        {
            "src": {"impl": f"{FAULTS}:SeqCorrupter", "params": {"count": 120}},
            "sink": sink("src/tick"),
        }
    )
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    row = table_row(log, "src/tick -> sink.tick")
    assert row["messages"] == 126  # 120 ticks and 6 undecodable frames
    assert row["bad"] == 6
    assert row["dropped"] == 0


def test_non_finite_messages_are_counted_and_warned_about_once_where_published() -> None:
    # Checked once per message by the publisher, not once per subscriber: every edge of
    # the topic shows the topic's count, and only the publisher warns.
    launcher, out = launcher_for(
        {
            "p": {"impl": f"{FAULTS}:BadPressure", "params": {"count": 40}},
            "s": {"impl": f"{FAULTS}:PressureSink", "inputs": {"pressure": "p/pressure"}},
            "t": {"impl": f"{FAULTS}:PressureSink", "inputs": {"pressure": "p/pressure"}},
        }
    )
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    for edge in ("p/pressure -> s.pressure", "p/pressure -> t.pressure"):
        row = table_row(log, edge)
        assert row["messages"] == 40
        assert row["nonfinite"] == 20
    warnings = [line for line in log.splitlines() if "non-finite" in line]
    assert len(warnings) == 1, log
    assert "[p]" in warnings[0], log
    assert "pressure_pa" in warnings[0] and "p/pressure" in warnings[0]


def test_a_node_restarts_after_the_fork_server_died() -> None:
    # Nodes are forks of the launcher's fork server; with it killed, a restart starts a
    # fresh server (a new Python) and the node comes back from there.
    a = ticker()
    a["restart"] = {"policy": "on-failure", "max_restarts": 1, "backoff_secs": 0.1}
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=10.0)
    seen: dict[str, object] = {}

    def kill_server_then_node(pid: int) -> None:
        assert launcher.starter is not None
        seen["server"] = launcher.starter.server
        seen["name"] = comm(pid)  # each node is named after itself in ps and top
        os.kill(launcher.starter.server, signal.SIGKILL)
        assert still_alive([launcher.starter.server]) == []  # gone before the node goes
        os.kill(pid, signal.SIGKILL)

    when_running(launcher, "a", kill_server_then_node)
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    assert seen["name"] == "a"
    assert "node 'a' failed (signal 9); restart 1/1" in log
    assert "node 'a' is back" in log
    assert launcher.starter is not None and launcher.starter.server != seen["server"]
    assert "a/tick" in log


def test_a_node_ending_with_sys_exit_and_a_message_fails_as_python_would() -> None:
    # A forked node ends through the fork server's code, not Python's: the same outcome
    # (the message on its output, exit code 1).
    launcher, out = launcher_for(
        {"a": ticker(exit_message="no sensor here"), "b": sink("a/tick")}, duration_secs=10.0
    )
    code = launcher.run()
    log = out.getvalue()
    assert code == 1, log
    assert "[a] no sensor here" in log
    assert launcher.procs["a"].exit_codes == [1]
