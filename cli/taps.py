"""Nodes the command line adds to a graph to listen to its topics: the recorder
(``--record``) and a viewer (``--view``).

Both are one shape: a node with one queued input per chosen topic of the checked graph,
under a name no node of the graph has yet.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from messages.errors import GraphError
from runtime.graph import check


def add_listener(
    doc: dict[str, Any],
    topics: list[str],
    *,
    name: str,
    impl: str,
    params: dict[str, Any],
    queue_size: int,
    required: bool,
) -> dict[str, Any]:
    """A copy of ``doc`` with node ``name`` (``_`` appended while taken) of ``impl``
    subscribed to each of ``topics`` (queued, at most ``queue_size`` waiting)."""
    doc = yaml.safe_load(yaml.safe_dump(doc))
    while name in doc["nodes"]:
        name += "_"
    doc["nodes"][name] = {
        "impl": impl,
        "params": params,
        "inputs": {
            f"t{i}": {"from": t, "policy": "queue", "queue_size": queue_size}
            for i, t in enumerate(topics)
        },
        "required": required,
    }
    return doc


def add_recorder(
    doc: dict[str, Any],
    path: Path,
    topics: str | None,
    command_line: str,
    source: str = "",
    *,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Return ``doc`` with a ``recorder`` node subscribed to every topic matching ``topics``
    (``overwrite``: it may replace a finished bag at ``path``)."""
    graph = check(doc)
    pattern = re.compile(topics or ".*")
    chosen = sorted(t for t in graph.providers() if pattern.search(t))
    if not chosen:
        raise GraphError(f"--record-topics {topics!r} matches no topic of the graph")
    params = {
        "path": str(path),
        "graph_yaml": yaml.safe_dump(graph.document, sort_keys=False),
        "graph_source": source,
        "command_line": command_line,
        "overwrite": overwrite,
    }
    return add_listener(
        doc,
        chosen,
        name="recorder",
        impl="recorder",
        params=params,
        queue_size=10000,
        required=True,
    )


def viewer_refused(target: str | None) -> str | None:
    """Why ``--view TARGET`` cannot run here (a window without a display), or None."""
    if target != "spawn":
        return None
    from viz.display import NoDisplay, require_display

    try:
        require_display("use `--view FILE.rrd` (saved here) or `--view foxglove`")
    except NoDisplay as err:
        return f"launch.py --view: {err}"
    return None


def add_viewer(doc: dict[str, Any], target: str, *, source: str = "") -> dict[str, Any]:
    """Return ``doc`` with a ``viewer.rerun`` (or ``viewer.foxglove``) node on every topic.

    ``target``: ``spawn`` (a Rerun viewer window), a path ending in ``.rrd`` (saved
    headless), or ``foxglove`` (Foxglove's live WebSocket server). The viewer is not
    required: a viewer that fails does not stop the graph.
    """
    graph = check(doc, source=source)
    topics = sorted(graph.providers())
    if not topics:
        raise GraphError(f"{source}: --view: the graph publishes no topic")
    foxglove = target == "foxglove"
    return add_listener(
        doc,
        topics,
        name="viewer",
        impl="viewer.foxglove" if foxglove else "viewer.rerun",
        params={} if foxglove else {"target": target},
        queue_size=1000,
        required=False,
    )
