"""What the command line imports before it does anything: only what the command needs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEAVY = {"torch", "scipy"}  # casadi and cv2 cost some 40 ms each: allowed

PROBE = """
import json, sys
sys.argv = ["launch.py", *json.loads(sys.argv[1])]
import launch
try:
    code = launch.main()
except SystemExit as exit:
    code = exit.code
mods = sorted(m for m in sys.modules if m.startswith("nodes.") or m.split(".")[0] in {heavy})
print(json.dumps({{"code": code, "modules": mods}}))
"""


def imported(*argv: str) -> tuple[object, set[str]]:
    """Run ``launch.py ARGV`` in a fresh interpreter: its exit code and the modules of
    ``nodes`` and the heavy libraries it imported."""
    probe = PROBE.format(heavy=sorted(HEAVY))
    done = subprocess.run(
        [sys.executable, "-c", probe, json.dumps(argv)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    result = json.loads(done.stdout.strip().splitlines()[-1])
    return result["code"], set(result["modules"])


@pytest.mark.parametrize("argv", [["--help"], ["bag", "info", "missing.mcap"]], ids=str)
def test_help_and_bag_info_import_no_node_module(argv: list[str]) -> None:
    _, modules = imported(*argv)
    assert modules == set()


def test_help_imports_not_even_numpy() -> None:
    probe = (
        "import sys; sys.argv = ['launch.py', '--help']; import launch\n"
        "try:\n    launch.main()\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'messages', 'zmq')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_check_imports_only_the_graphs_node_modules() -> None:
    code, modules = imported("graph.yaml", "--check")
    assert code == 0
    assert not modules & HEAVY, modules
    assert modules == {
        "nodes.world",
        "nodes.bubble_camera",
        "nodes.pressure",
        "nodes.gripper",
        "nodes.grasp_monitor",
        "nodes.shear_tracker",
        "nodes.wrench",
        "nodes.slip",
        "nodes.contact_patch",
        "nodes.pose_estimator",
        "nodes.supervisor",
        "nodes.supervisor.base",
        "nodes.supervisor.handover",
    }
