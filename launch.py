"""The command line: run, check, record, replay and inspect graphs.

python launch.py GRAPH [--check] [--set NODE.PARAM=VALUE ...] [--swap NODE=IMPL ...]
                       [--only NODE,NODE] [--duration SECS] [--log-level LEVEL]
                       [--record OUT.mcap [--record-topics REGEX] [--overwrite]] [--lockstep]
                       [--view [OUT.rrd | foxglove]] [--host NAME [--keys DIR]]
python launch.py nodes [IMPL]                list implementations, or one's ports and params
python launch.py bag info|echo|diff ...      inspect bags (see docs/bags.md)
python launch.py bag view|export|video ...   look at bags (see docs/viewing.md)
python launch.py replay BAG [--swap NODE[=IMPL] ...] [...]
python launch.py keys make HOST | list [--keys DIR]   CURVE keys of hosts (docs/hosts.md)
"""

from __future__ import annotations

import os
import signal
import sys


def _interrupted(signum: int, frame: object) -> None:
    """Ctrl-C or SIGTERM outside a running graph: end now, quietly, with 128 + N.

    Installed before anything else is imported, so a signal during start-up is never a
    traceback; the launcher installs its own handlers while it supervises a graph.
    """
    raise SystemExit(128 + signum)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, _interrupted)
    signal.signal(signal.SIGTERM, _interrupted)

# Nodes are forks of the launcher (runtime.child): numpy's BLAS on one thread in each
# unless the user says otherwise (a dozen processes share a few cores). Set before
# anything imports numpy, for `python launch.py` and the `softbubble` command alike.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402 - after the signal handlers, on purpose
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

# What each command needs is imported when it runs: ``--help`` and ``bag info`` never
# import a node module, ``--check`` only those the graph names (docs/runtime.md).


def run_parser() -> argparse.ArgumentParser:
    """The parser of ``launch.py GRAPH ...``; its help lists the subcommands too."""
    from runtime.cli import add_deprecated, add_run_options

    width = max(len(name) for name in SUBCOMMANDS)
    epilog = "subcommands (python launch.py COMMAND --help for each):\n" + "\n".join(
        f"  {name:{width}}  {summary}" for name, (summary, _) in SUBCOMMANDS.items()
    )
    parser = argparse.ArgumentParser(
        prog="python launch.py",
        usage=f"python launch.py GRAPH [options] | python launch.py {{{','.join(SUBCOMMANDS)}}} ...",
        description="Run a graph file (or check it with --check), or one of the subcommands.",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("graph", type=Path, help="the graph file (YAML)")
    parser.add_argument(
        "--check",
        action="store_true",
        help="check the graph (and every file its params name); start nothing",
    )
    add_run_options(parser, swap_metavar="NODE=IMPL", swap_help="another implementation")
    parser.add_argument("--only", default="", metavar="NODE,NODE", help="run only these nodes")
    parser.add_argument(
        "--view",
        nargs="?",
        const="spawn",
        default=None,
        metavar="OUT.rrd|foxglove",
        help="add a viewer: a Rerun window, an .rrd file, or a Foxglove live server",
    )
    add_deprecated(parser, "--topics", "--record-topics", "record_topics")
    return parser


def run_main(argv: list[str]) -> int:
    args = run_parser().parse_args(argv)
    if args.view == "spawn" and not args.check:
        from viz.display import NoDisplay, require_display

        try:
            require_display("use `--view FILE.rrd` (saved here) or `--view foxglove`")
        except NoDisplay as err:
            print(f"launch.py --view: {err}", file=sys.stderr)
            return 2
    import nodes  # noqa: F401 - the index of node implementations (no node module)
    from messages.errors import GraphError
    from runtime import graph as graphs
    from runtime.cli import shared_command_line
    from runtime.run import launch

    source = str(args.graph)
    try:
        doc = graphs.load_document(args.graph)
        only = [n for n in args.only.split(",") if n]
        doc = graphs.apply_overrides(
            doc, sets=args.sets, swaps=args.swaps, only=only, source=source
        )
        if args.view is not None:
            from runtime.taps import add_viewer

            doc = add_viewer(doc, args.view, source=source)
        checked = graphs.check(doc, source=source)
    except GraphError as err:
        print(f"graph check failed:\n{err}", file=sys.stderr)
        return 2
    if args.check:
        if args.host is not None:
            from runtime.run import check_here, host_keys

            try:
                keys = host_keys(checked, args.host, args.keys)
                check_here(checked, args.host)
            except GraphError as err:
                print(f"graph check failed:\n{err}", file=sys.stderr)
                return 2
            on = f"; host {args.host}" + (", its key matches" if keys else "")
        elif checked.hosts.table:
            on = f"; hosts: {', '.join(checked.hosts.table)} (run each with --host NAME)"
        else:
            on = ""
        print(f"{source}: OK, {len(checked.nodes)} nodes, {len(checked.edges())} edges{on}")
        return 0
    return launch(
        doc,
        source=source,
        record=args.record,
        topics=args.record_topics,
        overwrite=args.overwrite,
        lockstep=args.lockstep,
        duration_secs=args.duration,
        log_level=args.log_level,
        command_line=shared_command_line(sys.argv),
        host=args.host,
        key_dir=args.keys,
    )


def nodes_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python launch.py nodes",
        description="List node implementations (optional inputs in [brackets]); "
        "with IMPL, show its ports and parameters with defaults, units and limits.",
    )
    parser.add_argument("impl", nargs="?", help="a registered name or module:Class")
    args = parser.parse_args(argv)
    import nodes
    from runtime.cli import node_details, node_table
    from runtime.registry import known

    if args.impl is None:
        nodes.import_all()
        print(node_table(known()))
        return 0
    try:
        print(node_details(args.impl))
    except KeyError as err:
        print(f"launch.py nodes: {err.args[0]}", file=sys.stderr)
        return 2
    return 0


def bag_main(argv: list[str]) -> int:
    from runtime.bagtool import main as bag_tool

    return bag_tool(argv)


def replay_main(argv: list[str]) -> int:
    import nodes  # noqa: F401 - the index of node implementations
    from runtime.replaytool import replay_main as replay

    return replay(argv)


def keys_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python launch.py keys",
        description="Make or list the CURVE key pairs of a graph's hosts: the secret key "
        "stays in the key folder (mode 0600), the public key goes in the graph's hosts table.",
    )
    parser.add_argument("action", choices=("make", "list"))
    parser.add_argument("host", nargs="?", help="make: the host's name in the hosts table")
    parser.add_argument("--overwrite", action="store_true", help="make: replace a host's key")
    from runtime.cli import add_keys_option

    add_keys_option(parser)
    args = parser.parse_args(argv)
    from runtime.security import default_key_dir, list_keys, make_key

    key_dir = args.keys or default_key_dir()
    if args.action == "make":
        if not args.host:
            parser.error("keys make: name the host")
        try:
            keys = make_key(key_dir, args.host, overwrite=args.overwrite)
        except (FileExistsError, OSError) as err:
            print(f"launch.py keys: {err}", file=sys.stderr)
            return 2
        print(f"{key_dir / args.host}.key: secret key of host {args.host} (mode 0600)")
        print(f'its hosts-table entry: public_key: "{keys.public}"')
        return 0
    rows = list_keys(key_dir)
    for name, public, secret in rows:
        print(f"{name:16} {public}  {'secret key here' if secret else 'public key only'}")
    if not rows:
        print(f"no keys in {key_dir}")
    return 0


# name -> (what --help says, handler): each reads the rest of the command line.
SUBCOMMANDS: dict[str, tuple[str, Callable[[list[str]], int]]] = {
    "nodes": ("list node implementations; `nodes IMPL`: its ports and parameters", nodes_main),
    "bag": (
        "bags: info|echo|diff|recover (docs/bags.md), view|export|video (docs/viewing.md)",
        bag_main,
    ),
    "replay": ("replay a bag through its graph, some nodes swapped (docs/bags.md)", replay_main),
    "keys": ("make or list the CURVE keys of a graph's hosts (docs/hosts.md)", keys_main),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:
        return SUBCOMMANDS[argv[0]][1](argv[1:])
    return run_main(argv)


if __name__ == "__main__":
    sys.exit(main())
