"""The launcher's exit code says whether every required node ended well, whatever the
moment it failed: mid-run, in a restart that never came back, or while the graph stopped."""

from __future__ import annotations

from pathlib import Path

from tests.faults.conftest import sink, ticker
from tests.faults.test_supervision import launcher_for


def test_a_required_node_still_in_its_back_off_at_the_stop_fails_the_run(tmp_path: Path) -> None:
    a = ticker(crash_after=5, crash_marker=str(tmp_path / "crashed"))
    a["restart"] = {"policy": "on-failure", "backoff_secs": 600, "backoff_max_secs": 600}
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=3.0)
    code = launcher.run()
    log = out.getvalue()
    assert code == 1, log
    assert "node 'a' failed (exit code 3); restart 1/5 in 600.00 s" in log
    assert "required node 'a' failed (not back from restart 1 at the stop)" in log


def test_a_required_node_whose_restart_hangs_in_setup_fails_the_run(tmp_path: Path) -> None:
    a = ticker(crash_after=5, crash_marker=str(tmp_path / "crashed"), restarted_init_secs=120)
    a["restart"] = {"policy": "on-failure", "max_restarts": 1, "backoff_secs": 0.1}
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=4.0)
    code = launcher.run()
    log = out.getvalue()
    assert code == 1, log
    assert "node 'a' is back" not in log
    assert "required node 'a' failed (not back from restart 1 at the stop)" in log


def test_a_required_node_failing_while_the_graph_stops_fails_the_run() -> None:
    launcher, out = launcher_for(
        {"a": ticker(disk_full_at_stop=True), "b": sink("a/tick")}, duration_secs=2.0
    )
    code = launcher.run()
    log = out.getvalue()
    assert code == 1, log
    assert "No space left on device" in log
    assert "required node 'a' failed (exit code 1 while the graph stopped)" in log


def test_a_node_not_required_failing_at_the_stop_is_said_but_the_run_ends_well() -> None:
    a = ticker(disk_full_at_stop=True)
    a["required"] = False
    launcher, out = launcher_for({"a": a, "b": sink("a/tick")}, duration_secs=2.0)
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    assert "node 'a' failed (exit code 1 while the graph stopped); not required" in log
