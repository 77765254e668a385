"""A running graph, as tools outside it see it: ``status.json`` in the launcher's run folder.

The launcher rewrites the file about once a second from what it holds anyway (the
nodes' heartbeats): the graph file, the launcher's PID, seconds since the start, each
node's state, restarts, CPU seconds, publisher endpoint and counters, and each topic's
type, publisher, subscribers and message count. Written to a temporary file and renamed,
so a reader never sees half of it. The run folder is private to the user who runs the
graph (``runtime.isolation``), so are the endpoints a tool connects to.

:func:`find_runs` lists the running graphs of this user; :func:`pick_run` chooses one by
its run folder, PID or graph name. ``launch.py topic`` (``cli.topic``) reads them.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from messages.errors import GraphError
from runtime.counters import add_stats, topic_totals
from runtime.graph import Graph
from runtime.isolation import user_rundirs
from runtime.nodeprocs import Proc

STATUS_FILE = "status.json"
WRITE_EVERY_SECS = 1.0


def snapshot(graph: Graph, procs: Mapping[str, Proc], elapsed_secs: float) -> dict[str, Any]:
    """What ``status.json`` holds (see the module docstring)."""
    stats = {name: add_stats(p.stats_base, p.stats) for name, p in procs.items()}
    totals = topic_totals(stats)
    subscribers: dict[str, list[str]] = {}
    for topic, node, port in graph.edges():
        subscribers.setdefault(topic, []).append(f"{node}.{port}")
    topics = {}
    for topic, (node, kind) in sorted(graph.providers().items()):
        row = totals.get(topic, {})
        topics[topic] = {
            "type": kind.__name__,
            "publisher": node,
            "subscribers": sorted(subscribers.get(topic, [])),
            "messages": int(row.get("messages", 0)),
            "dropped": int(row.get("dropped", 0)) + int(row.get("superseded", 0)),
        }
    nodes = {}
    for name, proc in procs.items():
        inputs = stats[name].get("inputs", {})
        nodes[name] = {
            "state": proc.state,
            "restarts": proc.restarts,
            "cpu_secs": round(float(stats[name].get("cpu_secs", proc.cpu_secs)), 3),
            "pid": proc.process.pid if proc.process is not None else None,
            "endpoint": proc.endpoint,
            "dropped": sum(
                int(i.get("dropped", 0)) + int(i.get("superseded", 0)) for i in inputs.values()
            ),
        }
    return {
        "source": graph.source,
        "pid": os.getpid(),
        "elapsed_secs": round(elapsed_secs, 3),
        "written_unix": time.time(),
        "nodes": nodes,
        "topics": topics,
    }


def write(rundir: Path, status: Mapping[str, Any]) -> None:
    """Replace ``rundir/status.json`` with ``status`` in one rename."""
    fd, tmp = tempfile.mkstemp(dir=rundir, prefix=".status-")
    with os.fdopen(fd, "w") as out:
        json.dump(status, out)
    os.replace(tmp, rundir / STATUS_FILE)


@dataclass(frozen=True)
class Run:
    """A running graph: its run folder and its newest status."""

    rundir: Path
    status: dict[str, Any]

    @property
    def name(self) -> str:
        return Path(str(self.status.get("source", ""))).stem

    def endpoint(self, topic: str) -> str:
        """The publisher endpoint of ``topic`` (``GraphError`` names the topics there are)."""
        topics = self.status.get("topics", {})
        if topic not in topics:
            raise GraphError(
                f"{self.status.get('source')}: no topic {topic!r} (topics: {', '.join(topics)})"
            )
        node = topics[topic]["publisher"]
        endpoint = self.status["nodes"].get(node, {}).get("endpoint")
        if not endpoint:
            raise GraphError(
                f"{self.status.get('source')}: {node} (publisher of {topic}) is not running"
            )
        return str(endpoint)


def read(rundir: Path) -> Run | None:
    """The run in ``rundir``, or None when it has no readable status (yet)."""
    try:
        status = json.loads((rundir / STATUS_FILE).read_text())
    except (OSError, ValueError):
        return None
    return Run(rundir, status) if isinstance(status, dict) else None


def find_runs() -> list[Run]:
    """The running graphs of this user, newest first (a folder whose launcher is gone is not)."""
    runs = []
    for path, alive in user_rundirs():
        run = read(path) if alive else None
        if run is not None:
            runs.append(run)
    return sorted(runs, key=lambda r: -float(r.status.get("written_unix", 0)))


def pick_run(which: str | None, *, wait_secs: float = 0.0) -> Run:
    """The run named by ``which``: a run folder, a launcher PID or a graph name (the graph
    file's stem, ``graph`` for graph.yaml); None: the only running graph. ``wait_secs``:
    how long to wait for it to be running.

    Raises:
        GraphError: no such run (after ``wait_secs``), or several and ``which`` does not
            choose one.
    """
    end = time.monotonic() + wait_secs
    while True:
        try:
            return _pick(which)
        except GraphError:
            if time.monotonic() >= end:
                raise
            time.sleep(0.1)


def _pick(which: str | None) -> Run:
    if which and Path(which).is_dir():
        run = read(Path(which))
        if run is None:
            raise GraphError(f"{which}: not the run folder of a running graph (no {STATUS_FILE})")
        return run
    runs = find_runs()
    if which:
        runs = [
            r for r in runs if which in (r.name, str(r.status.get("pid")), r.status.get("source"))
        ]
    if len(runs) == 1:
        return runs[0]
    listed = "; ".join(f"{r.name} (pid {r.status.get('pid')}, {r.rundir})" for r in find_runs())
    if not runs:
        what = f"no running graph named {which!r}" if which else "no graph is running"
        raise GraphError(f"{what} (running: {listed or 'none'})")
    raise GraphError(f"{len(runs)} graphs are running: name one with --run ({listed})")
