"""``launch.py schema``: the JSON Schema of graph files, for editors (docs/runtime.md)."""

from __future__ import annotations

import argparse
import json


def main(args: argparse.Namespace) -> int:
    import nodes
    from runtime.graphschema import graph_schema
    from runtime.registry import known, resolve

    nodes.import_all()
    print(json.dumps(graph_schema({name: resolve(name) for name in known()}), indent=1))
    return 0
