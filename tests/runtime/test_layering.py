"""The library stands without the command line: the runtime never imports ``cli`` or ``viz``."""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import runtime

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import importlib, json, sys
for name in json.loads(sys.argv[1]):
    importlib.import_module(name)
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("cli", "viz", "launch"))))
"""


def runtime_modules() -> list[str]:
    """Every module of the runtime package (``runtime.child`` and the bag package too)."""
    found = pkgutil.walk_packages(runtime.__path__, prefix="runtime.")
    return ["runtime", *sorted(m.name for m in found)]


def loaded_by(modules: list[str]) -> list[str]:
    done = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(modules)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    result: list[str] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def test_import_runtime_loads_no_command_line_module() -> None:
    assert loaded_by(["runtime"]) == []


def test_no_runtime_module_loads_the_command_line_or_viz() -> None:
    modules = runtime_modules()
    assert {"runtime.launcher", "runtime.hostlink", "runtime.runner", "runtime.bag"} <= set(modules)
    assert loaded_by(modules) == []
