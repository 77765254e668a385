"""``launch.py schema [--out FILE]``: the JSON Schema of graph files, for editors
(docs/graphs.md)."""

from __future__ import annotations

import argparse
import json


def main(args: argparse.Namespace) -> int:
    import nodes
    from runtime.graphschema import graph_schema
    from runtime.registry import known, resolve

    nodes.import_all()
    text = json.dumps(graph_schema({name: resolve(name) for name in known()}), indent=1)
    if args.out is None:
        print(text)
    else:
        args.out.write_text(text + "\n")
    return 0
