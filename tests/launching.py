"""``python launch.py ...`` as a user runs it: a fresh Python, this checkout first on its path."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def launch_py(
    *args: str | Path, timeout: float = 240, cwd: Path = ROOT
) -> subprocess.CompletedProcess[str]:
    """Run ``launch.py ARGS`` in ``cwd`` (the checkout by default) and return its output as
    text; ``subprocess.TimeoutExpired`` past ``timeout`` seconds."""
    return subprocess.run(
        [sys.executable, str(ROOT / "launch.py"), *map(str, args)],
        cwd=cwd,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def launch_py_together(
    *runs: list[str | Path], timeout: float = 240, cwd: Path = ROOT
) -> list[subprocess.CompletedProcess[str]]:
    """Run several ``launch.py ARGS`` at once (each a list of arguments), as
    :func:`launch_py` runs one; their outputs, in order. Each of them is killed past
    ``timeout`` seconds, and ``subprocess.TimeoutExpired`` raised."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = [
        subprocess.Popen(
            [sys.executable, str(ROOT / "launch.py"), *map(str, args)],
            cwd=cwd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for args in runs
    ]
    done = []
    deadline = time.monotonic() + timeout
    try:
        for proc in procs:
            out, err = proc.communicate(timeout=max(0.0, deadline - time.monotonic()))
            done.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return done
