"""Helpers to run graphs through the real launcher in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterable
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


def end_table(log: str) -> dict[str, dict[str, int | float]]:
    """The launcher's end-of-run table (``runtime.counters.table``) in ``log``: per row
    (``topic -> node.port``, or ``topic (no reader here)``) its values by column name."""
    lines = [line.removeprefix("[launch] ") for line in log.splitlines()]
    start = next(i for i, line in enumerate(lines) if line.startswith("topic -> node.port "))
    names = lines[start].split()[3:]
    rows: dict[str, dict[str, int | float]] = {}
    for line in lines[start + 1 :]:
        if not line.strip():  # the per-node table follows
            break
        words = line.split()
        values = words[-len(names) :]
        name = " ".join(words[: -len(names)])
        rows[name] = dict(
            zip(names, (int(v) if v.isdigit() else float(v) for v in values), strict=True)
        )
    return rows


def table_row(log: str, edge: str) -> dict[str, int | float]:
    """The end-of-run table's row of ``edge`` (``topic -> node.port``), by column name."""
    rows = end_table(log)
    assert edge in rows, f"no row {edge!r} in the end-of-run table: {sorted(rows)}"
    return rows[edge]


def topic_messages(log: str, topic: str) -> int:
    """How many messages the end-of-run table says ``topic`` carried: the most of its rows
    (its edges' rows agree unless the topic was published on another host, where each
    counts what it received)."""
    counts = [
        int(row["messages"])
        for name, row in end_table(log).items()
        if name.split(" ", 1)[0] == topic
    ]
    assert counts, f"no row of topic {topic!r} in the end-of-run table"
    return max(counts)


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


def still_alive(pids: Iterable[int], timeout: float = 60.0) -> list[int]:
    """Those of ``pids`` still alive once they have ended: processes whose launcher died
    end on their own, however loaded the machine; ``timeout`` only makes one that never
    does a failure rather than a hang."""
    pids = sorted(set(pids))
    end = time.monotonic() + timeout
    while any(alive(p) for p in pids) and time.monotonic() < end:
        time.sleep(0.05)
    return [p for p in pids if alive(p)]
