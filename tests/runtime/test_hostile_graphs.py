"""Hostile graph files: ``--check`` refuses each in one line (exit 2), never a traceback or
a hang, and what passes the check is something a run can do."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from messages.errors import GraphError
from runtime import graph as graphs
from runtime.params import MAX_SECS, timer_period_nanos
from tests.synthetic_nodes import IMPLS

ROOT = Path(__file__).resolve().parents[2]
SOURCE = IMPLS["synthetic.source"]


def _bounded_memory() -> None:
    # A launcher reading /dev/zero would take every byte of a shared machine: 4 GiB of
    # address space ends it with a MemoryError instead (the check needs a few hundred MB).
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def check(path: Path | str, *args: str) -> subprocess.CompletedProcess[str]:
    """``launch.py PATH --check``: a hang fails the test after 60 s instead of hanging it."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, str(ROOT / "launch.py"), str(path), "--check", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=_bounded_memory,
    )


def refused(result: subprocess.CompletedProcess[str], *phrases: str) -> None:
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    for phrase in phrases:
        assert phrase in result.stderr, result.stderr


def source_graph(tmp_path: Path, params: str, extra: str = "", head: str = "") -> Path:
    path = tmp_path / "g.yaml"
    path.write_text(f"{head}nodes:\n  src: {{impl: '{SOURCE}', params: {params}{extra}}}\n")
    return path


def test_a_5000_digit_integer_is_refused_at_its_line(tmp_path: Path) -> None:
    result = check(source_graph(tmp_path, "{rate_hz: " + "1" * 5000 + "}"))
    refused(result, "g.yaml: YAML error", "an integer of 5000 digits", "line 2")


def test_an_alias_bomb_is_refused_before_it_expands(tmp_path: Path) -> None:
    head = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n"
    for i in range(1, 12):  # 9^12 values once expanded, 12 lines of text
        head += f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    result = check(source_graph(tmp_path, "{rate_hz: 1, x: *a11}", head=head))
    refused(result, "g.yaml: YAML error", "values once its aliases are expanded")


def test_parameters_nested_20000_deep_are_refused(tmp_path: Path) -> None:
    result = check(source_graph(tmp_path, "{rate_hz: 1, x: " + "[" * 20000 + "]" * 20000 + "}"))
    refused(result, "g.yaml: YAML error", "nested more than 64 levels deep")


def test_a_set_path_20000_keys_deep_is_refused(tmp_path: Path) -> None:
    path = source_graph(tmp_path, "{rate_hz: 1}")
    refused(check(path, "--set", "src." + ".".join(["a"] * 20000) + "=1"), "more than 64 keys")


@pytest.mark.parametrize("impl", ["./evil/x.py:C", "/tmp/x.py", "..a:B", "os:path/x"])
def test_an_impl_that_looks_like_a_path_is_one_line(tmp_path: Path, impl: str) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(f"nodes:\n  src: {{impl: '{impl}'}}\n")
    with pytest.raises(GraphError, match=r"node 'src'\.impl: "):
        graphs.load(path)


def test_a_scene_name_of_300_characters_is_one_line() -> None:
    result = check(ROOT / "graph.yaml", "--set", "world.scene=" + "s" * 300)
    refused(result, "node 'world'.params.scene", "File name too long")


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_is_not_read_as_a_graph(device: str) -> None:
    refused(check(device), f"{device}: cannot read graph file: not a regular file")


def test_a_fifo_is_not_opened_as_a_graph(tmp_path: Path) -> None:
    fifo = tmp_path / "g.yaml"
    os.mkfifo(fifo)  # opening it for reading would wait for a writer forever
    refused(check(fifo), "not a regular file")


def test_a_scene_that_is_a_device_is_refused() -> None:
    result = check(ROOT / "graph.yaml", "--set", "world.scene=/dev/zero")
    refused(result, "node 'world'.params.scene", "/dev/zero: cannot read scene: not a regular file")


def test_a_graph_over_the_size_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "g.yaml"
    path.write_text("# padding\n" * 200_000)
    refused(check(path), "larger than 1048576 bytes")


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ("{rate_hz: 1e-300}", "params.rate_hz"),  # a period of 1e300 s: int(inf) in the timer
        ("{rate_hz: 1e300}", "params.rate_hz"),  # a period of 0 ns: a busy loop
        ("{rate_hz: 18446744073709551617}", "params.rate_hz"),  # beyond 64 bits
    ],
)
def test_a_rate_no_timer_can_keep_fails_the_check(tmp_path: Path, params: str, field: str) -> None:
    with pytest.raises(GraphError, match=f"node 'src'.{field}: must be"):
        graphs.load(source_graph(tmp_path, params))


@pytest.mark.parametrize(
    "restart",
    [
        "{policy: on-failure, backoff_secs: 1e300, backoff_max_secs: 1e300}",
        "{policy: on-failure, backoff_max_secs: 1e300}",
        "{policy: on-failure, max_restarts: 100000}",  # 0.5 * 2**100000: OverflowError
    ],
)
def test_a_back_off_no_run_can_wait_fails_the_check(tmp_path: Path, restart: str) -> None:
    with pytest.raises(GraphError, match=r"node 'src'\.restart\.(backoff|max_restarts)"):
        graphs.load(source_graph(tmp_path, "{rate_hz: 1}", f", restart: {restart}"))


def test_the_timer_refuses_periods_it_cannot_keep() -> None:
    assert timer_period_nanos(0.5) == 500_000_000
    for bad in (0.0, 1e-300, 1e300, float("nan"), float("inf"), MAX_SECS * 2):
        with pytest.raises(ValueError, match="timer period_secs must be in"):
            timer_period_nanos(bad)
