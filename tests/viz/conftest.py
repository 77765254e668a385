"""One real short run of graph.yaml for the viz tests: ``launch.py graph.yaml --record BAG
--view LIVE.rrd`` (the default graph, a simulated mug handover that ends by itself in a
few seconds), so the live viewer node and the bag commands see the same messages."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("viz")
    bag, live = tmp / "run.mcap", tmp / "live.rrd"
    # The world at half real time: a loaded machine's perception keeps up, so the run holds
    # a tracked pose and the task's release before the scene ends (the tests expect both).
    cmd = [sys.executable, "launch.py", "graph.yaml", "--record", str(bag), "--view", str(live)]
    cmd += ["--set", "world.rate_scale=0.5"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [*cmd, "--duration", "20"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=180
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return bag, live
