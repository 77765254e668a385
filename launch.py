"""The command line: run, check, record, replay and inspect graphs.

python launch.py GRAPH [--check] [--set NODE.PARAM=VALUE ...] [--swap NODE=IMPL ...]
                       [--only NODE,NODE] [--duration SECS] [--log-level LEVEL]
                       [--record OUT.mcap [--topics REGEX] [--overwrite]] [--lockstep]
python launch.py nodes                       list every node implementation
python launch.py bag info|echo|diff ...      inspect bags (see docs/bags.md)
python launch.py replay BAG [--replace NODE=IMPL ...] [...]
"""

from __future__ import annotations

import argparse
import shlex
import signal
import sys
from pathlib import Path

# What each command needs is imported when it runs: ``--help`` and ``bag info`` never
# import a node module, ``--check`` only those the graph names (docs/runtime.md).


def _interrupted(signum: int, frame: object) -> None:
    """Ctrl-C or SIGTERM outside a running graph: end now, quietly, with 128 + N.

    Installed before anything heavy is imported, so a signal during start-up is never a
    traceback; the launcher installs its own handlers while it supervises a graph.
    """
    raise SystemExit(128 + signum)


def run_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python launch.py", description="Run a graph file.")
    parser.add_argument("graph", type=Path, help="the graph file (YAML)")
    parser.add_argument("--check", action="store_true", help="only check the graph; start nothing")
    parser.add_argument(
        "--set", dest="sets", action="append", default=[], metavar="NODE.PARAM=VALUE"
    )
    parser.add_argument("--swap", dest="swaps", action="append", default=[], metavar="NODE=IMPL")
    parser.add_argument("--only", default="", metavar="NODE,NODE", help="run only these nodes")
    parser.add_argument("--duration", type=float, default=None, metavar="SECS")
    parser.add_argument(
        "--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"]
    )
    parser.add_argument("--record", type=Path, default=None, metavar="OUT.mcap")
    parser.add_argument(
        "--topics", default=None, metavar="REGEX", help="with --record: topics to keep"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="with --record: replace a finished bag"
    )
    parser.add_argument("--lockstep", action="store_true", help="deterministic replay mode")
    args = parser.parse_args(argv)
    import nodes  # noqa: F401 - the index of node implementations (no node module)
    from messages.errors import GraphError
    from runtime import graph as graphs
    from runtime.launcher import launch

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
    if args.check:
        print(f"{source}: OK, {len(checked.nodes)} nodes, {len(checked.edges())} edges")
        return 0
    return launch(
        doc,
        source=source,
        record=args.record,
        topics=args.topics,
        overwrite=args.overwrite,
        lockstep=args.lockstep,
        duration_secs=args.duration,
        log_level=args.log_level,
        command_line=shlex.join([sys.executable, *sys.argv]),
    )


def list_nodes() -> int:
    import nodes
    from runtime.registry import known, resolve

    nodes.import_all()
    for name in known():
        cls = resolve(name)
        ins = ", ".join(f"{p}:{t.__name__}" for p, t in cls.inputs.items()) or "-"
        outs = ", ".join(f"{p}:{t.__name__}" for p, t in cls.outputs.items()) or "-"
        print(f"{name:32} in: {ins}  out: {outs}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["nodes"]:
        return list_nodes()
    if argv[:1] == ["bag"]:
        from runtime.bagtool import main as bag_main

        return bag_main(argv[1:])
    if argv[:1] == ["replay"]:
        import nodes  # noqa: F401 - the index of node implementations
        from runtime.bagtool import replay_main

        return replay_main(argv[1:])
    return run_main(argv)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, _interrupted)
    signal.signal(signal.SIGTERM, _interrupted)
    sys.exit(main())
