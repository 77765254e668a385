"""``python launch.py ...`` as a user runs it: a fresh Python, this checkout first on its path."""

from __future__ import annotations

import os
import subprocess
import sys
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
