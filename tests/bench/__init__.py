"""Smoke tests of ``bench/``: each bench at its ``--quick`` size."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def run_quick(name: str, *args: str, timeout: float) -> tuple[dict[str, Any], str]:
    """``python -m bench.NAME --quick --json ARGS`` from the repository root: its report
    and its stderr (the progress lines); it must exit 0."""
    done = subprocess.run(
        [sys.executable, "-m", f"bench.{name}", "--quick", "--json", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout), done.stderr
