"""Ctrl-C, SIGTERM and SIGKILL at every phase of a run: how it ends and what it leaves.

The goal is an end within 2 s of the signal: ``python -m bench.startup`` measures it.
These tests judge what the end says, not the machine's clock: the exit code, the phase
the run never reached (the nodes still import for 30 s; a ticker ticks forever: only the
signal or the failure ends it), the launcher's own account, and nothing left behind.
"""

from __future__ import annotations

import os
import signal
import time

import pytest

from tests.faults.conftest import FAULTS, sink, ticker
from tests.runtime.conftest import alive

CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
SIGNALS = pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["INT", "TERM"])


def assert_clean_end(r, signum: int, code: int) -> None:
    assert code == CODES[signum], r.log
    assert "Traceback" not in r.log and "KeyboardInterrupt" not in r.log, r.log
    assert r.leftovers() == ([], []), r.log


@SIGNALS
def test_signal_during_the_launchers_own_start_up(run, signum: int) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for_handlers()  # launch.py runs: it imports, checks the graph, or spawns
    assert r.proc.poll() is None
    code = r.signal_and_wait(signum)
    assert_clean_end(r, signum, code)


@SIGNALS
def test_signal_while_nodes_are_still_importing(run, signum: int) -> None:
    r = run({"a": ticker(init_secs=30.0), "b": sink("a/tick")})
    r.wait_for("starting 2 node(s)")
    r.wait_for_kids(2)
    time.sleep(0.5)
    code = r.signal_and_wait(signum)
    assert_clean_end(r, signum, code)
    assert "all nodes ready" not in r.log


@SIGNALS
def test_signal_while_running(run, signum: int) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    code = r.signal_and_wait(signum)
    assert_clean_end(r, signum, code)
    assert "a/tick" in r.log  # the end-of-run table


def test_sigterm_with_a_stopped_node(run) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    os.kill(r.note_kids()[0], signal.SIGSTOP)
    code = r.signal_and_wait(signal.SIGTERM)
    assert_clean_end(r, signal.SIGTERM, code)
    assert "1 node(s) still running: sending SIGKILL" in r.log, r.log  # it did not wait


@pytest.mark.parametrize("phase", ["launcher start-up", "nodes importing", "running"])
def test_killed_launcher_leaves_nothing(run, phase: str) -> None:
    r = run(
        {"a": ticker(init_secs=30.0 if phase == "nodes importing" else 0.0), "b": sink("a/tick")}
    )
    if phase == "launcher start-up":
        r.wait_for_kids(1)  # the run folder exists; the nodes are being spawned
    elif phase == "nodes importing":
        r.wait_for_kids(2)
        time.sleep(0.3)
    else:
        r.wait_for("all nodes ready")
    code = r.signal_and_wait(signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert r.leftovers() == ([], []), r.log


def test_required_node_killed_while_running_fails_the_run(run) -> None:
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    os.kill(r.note_kids()[0], signal.SIGKILL)
    code = r.finish(timeout=30)  # the ticker ticks forever: only the failure ends the run
    assert code == 1, r.log
    assert "required node 'a' failed (signal 9)" in r.log
    assert r.leftovers() == ([], []), r.log


def test_node_killed_while_importing_fails_the_start(run) -> None:
    r = run({"a": ticker(init_secs=30.0), "b": sink("a/tick")})
    kids = r.wait_for_kids(2)
    time.sleep(0.3)
    os.kill(kids[0], signal.SIGKILL)
    code = r.finish(timeout=30)
    assert code == 1, r.log
    assert "all nodes ready" not in r.log, r.log  # not after b's 30 s import
    assert "died during start-up" in r.log
    assert r.leftovers() == ([], []), r.log


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL], ids=["TERM", "KILL"])
def test_what_a_node_started_goes_with_it(run, tmp_path, signum: int) -> None:
    pid_file = tmp_path / "helper.pid"
    spawner = {"impl": f"{FAULTS}:Spawner", "params": {"pid_file": str(pid_file)}}
    r = run({"a": spawner, "b": sink("a/tick")})
    r.wait_for("all nodes ready")
    helper = int(pid_file.read_text())
    assert alive(helper)
    r.kids.add(helper)
    r.signal_and_wait(signum)
    assert r.leftovers() == ([], []), r.log


def test_a_stale_run_folder_is_swept_by_the_next_launcher(tmp_path, monkeypatch) -> None:
    """Killed between creating its folder and starting its first node (a few ms), a
    launcher leaves the folder; the next one removes it (its PID is gone)."""
    import subprocess
    import sys

    from runtime import isolation

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(isolation.tempfile, "tempdir", None)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = tmp_path / f"sbg-{dead.stdout.strip()}-x1"
    stale.mkdir()
    (stale / "control").touch()
    live = tmp_path / f"sbg-{os.getpid()}-x2"  # a launcher that still runs
    live.mkdir()
    fresh = isolation.make_rundir()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, fresh.name])


@pytest.mark.parametrize("after_secs", [0.0, 0.3, 1.0])
def test_three_quick_ctrl_cs_end_with_130(run, after_secs: float) -> None:
    # Whichever phase the first meets, the later ones may arrive while Python shuts down,
    # where a signal would take its default action again (death by SIGINT: -2).
    r = run({"a": ticker(), "b": sink("a/tick")})
    r.wait_for_handlers()
    time.sleep(after_secs)
    r.note_kids()
    for _ in range(3):
        r.proc.send_signal(signal.SIGINT)
        time.sleep(0.001)
    code = r.finish(timeout=30)
    assert code == 130, r.log
    assert "Traceback" not in r.log and "KeyboardInterrupt" not in r.log, r.log
    assert r.leftovers() == ([], []), r.log
