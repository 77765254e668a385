"""``launch.py graph GRAPH --draw OUT``: a picture of a graph file (``viz.graph_picture``).

The graph is checked first (with ``--set``, ``--swap`` and ``--only`` as ``run`` takes
them), so the picture shows the topics and types the launcher would wire.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from messages.errors import GraphError
from runtime import graph as graphs
from viz.graph_picture import Edge, draw


def main(args: argparse.Namespace) -> int:
    """Draw the graph; 0, or 2 when the graph does not check or the picture fails."""
    import nodes  # noqa: F401 - the index of node implementations

    source = str(args.graph)
    try:
        doc = graphs.load_document(args.graph)
        only = [n for n in args.only.split(",") if n]
        doc = graphs.apply_overrides(
            doc, sets=args.sets, swaps=args.swaps, only=only, source=source
        )
        checked = graphs.check(doc, source=source)
    except GraphError as err:
        print(f"graph check failed:\n{err}", file=sys.stderr)
        return 2
    types = checked.providers()
    node_impls = {name: str(doc["nodes"][name].get("impl", "")) for name in checked.nodes}
    edges = [
        Edge(topic, types[topic][1].__name__, types[topic][0], node, port)
        for topic, node, port in checked.edges()
    ]
    try:
        written, note = draw(node_impls, edges, args.draw, title=source)
    except (ValueError, OSError, subprocess.CalledProcessError) as err:
        print(f"graph --draw: {err}", file=sys.stderr)
        return 2
    if note:
        print(note, file=sys.stderr)
    print(f"{written}: {len(node_impls)} nodes, {len(edges)} edges")
    return 0
