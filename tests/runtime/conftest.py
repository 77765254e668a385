"""Helpers to run graphs through the real launcher in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from runtime.child import SERVER_NAME
from tests.synthetic_nodes import IMPLS

ROOT = Path(__file__).resolve().parents[2]


class GraphRun:
    def __init__(self, tmp_path: Path) -> None:
        self.tmp = tmp_path

    def write(self, nodes: dict, name: str = "graph.yaml") -> Path:
        """Write a graph for a launcher subprocess, which registers only production
        nodes: the synthetic nodes' names become their ``module:Class``."""
        portable = {
            node: {**spec, "impl": IMPLS.get(spec.get("impl", ""), spec.get("impl"))}
            for node, spec in nodes.items()
        }
        path = self.tmp / name
        path.write_text(yaml.safe_dump({"nodes": portable}))
        return path

    def start(self, graph: Path, *args: str) -> subprocess.Popen[str]:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        return subprocess.Popen(
            [sys.executable, str(ROOT / "launch.py"), str(graph), *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )

    def run(self, graph: Path, *args: str, timeout: float = 90) -> tuple[int, str]:
        proc = self.start(graph, *args)
        out, _ = proc.communicate(timeout=timeout)
        return proc.returncode, out

    def rows(self, path: Path) -> list[dict]:
        return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture
def graph_run(tmp_path: Path) -> GraphRun:
    return GraphRun(tmp_path)


def sink(out: Path, topic: str) -> dict:
    """A ``synthetic.sink`` node that writes what it receives on ``topic`` to ``out``."""
    return {"impl": "synthetic.sink", "params": {"out_path": str(out)}, "inputs": {"tick": topic}}


def table_row(log: str, edge: str) -> dict[str, int]:
    """The end-of-run table's row of ``edge`` (``topic -> node.port``), by column name."""
    header = next(line for line in log.splitlines() if line.startswith("[launch] topic -> "))
    names = header.split()[4:]
    row = next(line for line in log.splitlines() if line.startswith(f"[launch] {edge} "))
    values = row.removeprefix(f"[launch] {edge} ").split()
    return dict(zip(names, (int(v) if v.isdigit() else float(v) for v in values), strict=True))


def children_of(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    kids: list[int] = []
    task_dir = Path(f"/proc/{pid}/task")
    for task in task_dir.iterdir() if task_dir.exists() else []:
        try:
            kids += [int(p) for p in (task / "children").read_text().split()]
        except OSError:
            pass
    return kids


def nodes_of(pid: int) -> list[int]:
    """The node processes among ``pid``'s children (the launcher's fork server aside)."""
    return [k for k in children_of(pid) if is_node(k)]


def is_node(pid: int) -> bool:
    """Whether a child of a launcher is one of its nodes, not its fork server."""
    return comm(pid) != SERVER_NAME


def comm(pid: int) -> str:
    """What ``ps`` calls ``pid`` ("" once it is gone)."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def alive(pid: int) -> bool:
    """True if ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
