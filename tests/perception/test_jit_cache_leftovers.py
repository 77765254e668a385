"""A process killed during a cold compile leaves its build folder; the next compile removes it."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import pytest

from perception.pose import jit_cache

ROOT = Path(__file__).resolve().parents[2]


def slow_compiler(tmp_path: Path) -> Path:
    """A 'compiler' that says who it is and then takes a minute to compile."""
    path = tmp_path / "slowcc"
    path.write_text('#!/bin/sh\n[ "$1" = --version ] && { echo slowcc 1; exit 0; }\nsleep 60\n')
    path.chmod(0o755)
    return path


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_a_build_folder_left_by_a_killed_compile_is_removed_on_the_next_start(
    tmp_path: Path,
) -> None:
    cache = tmp_path / "cache"
    code = (
        "import casadi as ca; from perception.pose import jit_cache; x = ca.SX.sym('x'); "
        "jit_cache.library([ca.Function('cube', [x], [x * x * x])], name='cube', "
        f"compiler={str(slow_compiler(tmp_path))!r}, cache_dir={str(cache)!r})"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, start_new_session=True)
    try:
        end = time.monotonic() + 60
        while not list(cache.glob(".build-*/cube.c")) and time.monotonic() < end:
            time.sleep(0.05)
        assert list(cache.glob(".build-*/cube.c")), "the compile never started"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # a pose node killed mid-compile, compiler too
        proc.wait(timeout=10)
    assert len(list(cache.glob(".build-*"))) == 1  # what a kill leaves behind
    x = ca.SX.sym("x")
    lib = jit_cache.library(
        [ca.Function("sq", [x], [x * x])], name="sq", compiler="gcc", cache_dir=cache
    )
    assert lib.is_file()
    assert list(cache.glob(".build-*")) == []


def test_a_live_process_build_folder_is_left_alone(tmp_path: Path) -> None:
    mine = tmp_path / f"{jit_cache.BUILD_PREFIX}{os.getpid()}-abc"
    mine.mkdir()
    assert jit_cache.remove_stale_builds(tmp_path) == []
    assert mine.is_dir()
