"""``launch.py replay``: a bag through its graph, some nodes swapped (see docs/bags.md).

python launch.py replay FILE [--graph G] [--swap NODE[=IMPL] ...] [--rate X | --fast]
                        [--loop] [--start S] [--end E] [--replay-topics RE] [--remap A=B ...]
                        [--lockstep] [--strict] [--record OUT [--record-topics RE] [--overwrite]]
                        [--duration S] [--host NAME [--keys DIR] | --no-hosts]
                        [--set NODE.PARAM=VALUE ...] [--print-graph]

The graph it runs is :func:`runtime.replaygraph.build_replay_graph`'s.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import yaml

from cli.options import same_file
from cli.taps import add_viewer, viewer_refused
from messages.errors import BagError, GraphError
from runtime.bag import BagReader
from runtime.hosts import without_hosts
from runtime.replaygraph import ReplayOptions, build_replay_graph


def _pairs(values: Sequence[str], flag: str, *, allow_bare: bool = False) -> dict[str, str]:
    out = {}
    for value in values:
        key, sep, rest = value.partition("=")
        if not key or (not sep and not allow_bare) or (sep and not rest):
            raise SystemExit(f"{flag} {value!r}: expected NAME=VALUE")
        out[key] = rest
    return out


def main(args: argparse.Namespace) -> int:
    """``launch.py replay ...``: build the replay graph and run it (exit code)."""
    import nodes  # noqa: F401 - the index of node implementations (no node module)

    if args.record is not None and same_file(args.record, args.bag):
        print(
            f"replay: --record {args.record} is the bag being replayed ({args.bag}); "
            "recording onto it would destroy it: give another file",
            file=sys.stderr,
        )
        return 2
    refused = None if args.print_graph else viewer_refused(args.view)
    if refused:
        print(refused, file=sys.stderr)
        return 2
    try:
        if args.graph is not None:
            from runtime.graphfile import load_document

            graph = load_document(args.graph)
        else:
            with BagReader(args.bag) as reader:
                text = reader.run_info().get("graph_yaml", "")
            if not text:
                print(f"{args.bag}: the bag stores no graph; pass --graph", file=sys.stderr)
                return 2
            from runtime.graphfile import parse_yaml

            graph = parse_yaml(text, f"{args.bag}: the stored graph")
        if args.no_hosts:
            if args.host is not None:
                raise GraphError("--no-hosts and --host: give one of them")
            graph = without_hosts(graph)
        options = ReplayOptions(
            rate=args.rate,
            fast=args.fast,
            loop=args.loop,
            start_secs=args.start,
            end_secs=args.end,
            topics=args.replay_topics,
            remap=_pairs(args.remap, "--remap"),
            lockstep=args.lockstep,
            strict=args.strict,
        )
        replay_graph = build_replay_graph(
            graph, args.bag, _pairs(args.swaps, "--swap", allow_bare=True), options
        )
        if args.sets:
            from runtime.graph import apply_overrides

            replay_graph = apply_overrides(replay_graph, sets=args.sets, source=str(args.bag))
        if args.view is not None:
            replay_graph = add_viewer(replay_graph, args.view, source=f"{args.bag} (replay)")
    except (BagError, GraphError, ValueError) as err:
        print(f"replay: {err}", file=sys.stderr)
        return 2
    if args.print_graph:
        print(yaml.safe_dump(replay_graph, sort_keys=False), end="")
        return 0
    from cli.run import launch

    return launch(
        replay_graph,
        source=f"{args.bag} (replay)",
        record=args.record,
        topics=args.record_topics,
        overwrite=args.overwrite,
        # Counts are tracked in every mode, so that the replay node, when it has published
        # everything, can wait for the graph to drain before it asks it to stop.
        lockstep=True,
        duration_secs=args.duration,
        log_level=args.log_level,
        command_line=args.command_line,
        host=args.host,
        key_dir=args.keys,
    )
