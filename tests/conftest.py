"""Registers the test-only nodes (``synthetic.*``) in every test process; shared fixtures;
the test tiers.

Tiers. A test that starts a process (a launcher, a node, a command, a fork) is marked
``spawns``: every test in the files and folders of :data:`SPAWNING` is; one that starts
nothing but takes seconds of CPU is marked ``slow`` (:data:`SLOW`). ``make test`` runs
everything; ``make test-fast`` (``pytest -m "not spawns and not slow"``) runs the rest,
the unit tests, in under a minute. The fast tier keeps the marking honest: there a test
that starts a process fails, naming the list to add its file to.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Any

import pytest

import tests.synthetic_nodes  # noqa: F401  (registers synthetic.source, .relay, .merge, .sink)
from messages.base import Message

ROOT = Path(__file__).resolve().parents[1]
# Paths (relative to the repository, a folder ends with "/") whose tests start processes.
SPAWNING = (
    "tests/bench/",
    "tests/cli/",
    "tests/faults/",
    "tests/hosts/",
    "tests/devices/test_emulated_rig.py",
    "tests/devices/test_gripper_nodes.py",
    "tests/messages/test_types.py",
    "tests/perception/test_jit_cache_leftovers.py",
    "tests/perception/test_pose_solvers.py",
    "tests/runtime/test_bag.py",
    "tests/runtime/test_bag_e2e.py",
    "tests/runtime/test_bag_faults.py",
    "tests/runtime/test_bag_formats.py",
    "tests/runtime/test_bag_hostile.py",
    "tests/runtime/test_first_hour.py",
    "tests/runtime/test_graph_check.py",
    "tests/runtime/test_hostile_graphs.py",
    "tests/runtime/test_introspection.py",
    "tests/runtime/test_launcher.py",
    "tests/runtime/test_layering.py",
    "tests/runtime/test_lockstep_graphs.py",
    "tests/runtime/test_registry.py",
    "tests/runtime/test_verdict.py",
    "tests/sim/test_pattern.py",
    "tests/test_docs.py",
    "tests/test_graphs.py",
    "tests/test_tasks.py",
    "tests/viz/test_graph_picture.py",
    "tests/viz/test_headless.py",
)
# Tests that start nothing but take seconds of CPU each (hard solves, training, video).
SLOW = (
    "tests/nodes/test_force_nodes.py",
    "tests/perception/test_classify_train.py",
    "tests/perception/test_pose_hard.py",
    "tests/viz/test_viz.py",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        where = Path(str(item.fspath)).resolve().relative_to(ROOT).as_posix()
        if where.startswith(SPAWNING):
            item.add_marker(pytest.mark.spawns)
        if where.startswith(SLOW):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _processes_only_where_marked(request: pytest.FixtureRequest) -> Any:
    """In the fast tier (``-m "not spawns"``), a test that starts a process fails."""
    if "not spawns" not in (request.config.option.markexpr or ""):
        yield
        return

    def refuse(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError(
            f"{request.node.nodeid} starts a process: add its file to SPAWNING in "
            "tests/conftest.py (the `spawns` tier, run by `make test`, not `make test-fast`)"
        )

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(os, "fork", refuse)
        patch.setattr(os, "posix_spawn", refuse)
        patch.setattr(subprocess.Popen, "__init__", refuse)
        yield


@pytest.fixture
def scratch_registry(monkeypatch: pytest.MonkeyPatch) -> dict[str, type[Message]]:
    """A copy of the message registry for the test, so throwaway types never leak."""
    registry = dict(Message.registry)
    monkeypatch.setattr(Message, "registry", registry)
    return registry
