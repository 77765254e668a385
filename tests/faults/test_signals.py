"""Ctrl-C, SIGTERM and SIGKILL at every phase of a run: how it ends and what it leaves.

The goal is an end within 2 s of the signal (``python -m bench.startup`` measures it on a
quiet machine); these tests allow 6 s on a loaded one.
"""

from __future__ import annotations

import os
import signal
import time

import pytest

from tests.faults.conftest import sink, ticker

EXIT_SECS = 6.0
CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
SIGNALS = pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["INT", "TERM"])


def assert_clean_end(r, signum: int, code: int, took: float) -> None:
    assert code == CODES[signum], r.log
    assert took < EXIT_SECS, f"{took:.1f} s to exit\n{r.log}"
    assert "Traceback" not in r.log and "KeyboardInterrupt" not in r.log, r.log
    assert r.leftovers() == ([], []), r.log


@SIGNALS
def test_signal_during_the_launchers_own_start_up(run, signum: int) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for_handlers()  # launch.py runs: it imports, checks the graph, or spawns
    assert r.proc.poll() is None
    code, took = r.signal_and_time(signum)
    assert_clean_end(r, signum, code, took)


@SIGNALS
def test_signal_while_nodes_are_still_importing(run, signum: int) -> None:
    r = run({"a": ticker(init_secs=30.0), "b": sink("a/tick")})
    r.wait_for("starting 2 node(s)")
    r.wait_for_kids(2)
    time.sleep(0.5)
    code, took = r.signal_and_time(signum)
    assert_clean_end(r, signum, code, took)
    assert "all nodes ready" not in r.log


@SIGNALS
def test_signal_while_running(run, signum: int) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    code, took = r.signal_and_time(signum)
    assert_clean_end(r, signum, code, took)
    assert "a/tick" in r.log  # the end-of-run table


def test_sigterm_with_a_stopped_node(run) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    os.kill(r.note_kids()[0], signal.SIGSTOP)
    code, took = r.signal_and_time(signal.SIGTERM)
    assert_clean_end(r, signal.SIGTERM, code, took)


@pytest.mark.parametrize("phase", ["launcher start-up", "nodes importing", "running"])
def test_killed_launcher_leaves_nothing(run, phase: str) -> None:
    r = run(
        {"a": ticker(init_secs=30.0 if phase == "nodes importing" else 0.0), "b": sink("a/tick")}
    )
    if phase == "launcher start-up":
        r.wait_for("starting 2 node(s)")  # the run folder exists; children are being spawned
    elif phase == "nodes importing":
        r.wait_for_kids(2)
        time.sleep(0.3)
    else:
        r.wait_for("all nodes ready")
    code, _ = r.signal_and_time(signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert r.leftovers() == ([], []), r.log


def test_required_node_killed_while_running_fails_the_run(run) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    killed = time.monotonic()
    os.kill(r.note_kids()[0], signal.SIGKILL)
    code = r.finish(timeout=30)
    assert code == 1, r.log
    assert time.monotonic() - killed < EXIT_SECS
    assert "required node 'a' failed (signal 9)" in r.log
    assert r.leftovers() == ([], []), r.log


def test_node_killed_while_importing_fails_the_start(run) -> None:
    r = run({"a": ticker(init_secs=30.0), "b": sink("a/tick")})
    kids = r.wait_for_kids(2)
    time.sleep(0.3)
    killed = time.monotonic()
    os.kill(kids[0], signal.SIGKILL)
    code = r.finish(timeout=30)
    assert code == 1, r.log
    assert time.monotonic() - killed < EXIT_SECS, r.log
    assert "died during start-up" in r.log
    assert r.leftovers() == ([], []), r.log
