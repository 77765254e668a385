"""The command line's one argparse tree: ``python launch.py COMMAND ...`` (or ``softbubble``).

python launch.py [run] GRAPH [--check] [--set NODE.PARAM=VALUE ...] [--swap NODE=IMPL ...]
                       [--only NODE,NODE] [--duration SECS] [--log-level LEVEL]
                       [--record OUT.mcap [--record-topics REGEX] [--overwrite]] [--lockstep]
                       [--view [OUT.rrd | foxglove]] [--host NAME [--keys DIR]]
                       [--emulate [--rig FILE]]
python launch.py nodes [IMPL]                list implementations, or one's ports and params
python launch.py schema [--out FILE]        the JSON Schema of graph files, for editors
python launch.py graph GRAPH --draw OUT.svg  a picture of a graph file (docs/graphs.md)
python launch.py bag info|echo|diff ...      inspect bags (see docs/bags.md)
python launch.py bag view|export|video ...   look at bags (see docs/viewing.md)
python launch.py replay BAG [--swap NODE[=IMPL] ...] [...]
python launch.py topic list|echo|hz|nodes ...  look into a running graph (docs/runtime.md)
python launch.py keys make HOST | list [--keys DIR]   CURVE keys of hosts (docs/hosts.md)
python launch.py calibrate --out rigs/NAME.yaml [...]   calibrate a rig (docs/devices.md)
python launch.py batch replay|autolabel ...  many bags or worlds as tasks on Ray (docs/batch.md)

``run`` is the default command: ``launch.py GRAPH ...`` is ``launch.py run GRAPH ...``.
The tree is declared here, whole; each command's work is its module's ``main(args)``
(``cli.run``, ``cli.nodes``, ``cli.schema``, ``cli.graphdraw``, ``cli.bag``, ``cli.bagview``, ``cli.replay``, ``cli.topic``,
``cli.keys``),
imported when that command runs: ``--help`` imports neither numpy nor ZeroMQ, ``bag
info`` no node module, ``--check`` only those the graph names (docs/runtime.md).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from cli.options import (
    add_deprecated,
    add_keys_option,
    add_run_options,
    add_view_option,
    positive_secs,
    shared_command_line,
)

if TYPE_CHECKING:
    Commands = argparse._SubParsersAction[argparse.ArgumentParser]  # add_subparsers' result

BAG_VIEW = {
    "view": "log a bag to the Rerun viewer, or to an .rrd file (docs/viewing.md)",
    "export": "write a bag for Foxglove, or as a ROS 2 bag (docs/viewing.md)",
    "video": "a video (and stills) of a bag's cameras, overlays and task (docs/viewing.md)",
}


def parser() -> tuple[argparse.ArgumentParser, list[str]]:
    """The whole tree (every command and its options; ``COMMAND --help`` for each), and
    the commands' names."""
    top = argparse.ArgumentParser(
        prog="python launch.py",
        description="Run or check a graph file, or inspect, replay and view bags.",
        epilog="`python launch.py GRAPH ...` runs a graph (`run` is the default command).",
    )
    commands = top.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in (_run, _nodes, _schema, _graph, _bag, _replay, _topic, _keys, _calibrate, _batch):
        add(commands)
    return top, list(commands.choices)


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` (default: this process's command line) and run its command."""
    words = list(sys.argv[1:] if argv is None else argv)
    top, names = parser()
    if words and words[0] not in names and words[0] not in ("-h", "--help"):
        words.insert(0, "run")
    args = top.parse_args(words)
    # The command line as every host of a graph runs it, to record and compare.
    args.command_line = shared_command_line(sys.argv if argv is None else ["launch.py", *argv])
    code: int = importlib.import_module(args.handler).main(args)
    return code


def _run(commands: Commands) -> None:
    """``run GRAPH ...`` (``launch.py GRAPH ...`` without the word is the same)."""
    parser = commands.add_parser(
        "run",
        help="run a graph file, or check it with --check (the default command)",
        description="Run a graph file (or check it with --check). "
        "`python launch.py GRAPH ...` is `python launch.py run GRAPH ...`.",
    )
    parser.add_argument("graph", type=Path, help="the graph file (YAML)")
    parser.add_argument(
        "--check",
        action="store_true",
        help="check the graph (and every file its params name); start nothing",
    )
    add_run_options(parser, swap_metavar="NODE=IMPL", swap_help="another implementation")
    parser.add_argument("--only", default="", metavar="NODE,NODE", help="run only these nodes")
    _add_emulate(parser, "run a hardware graph against emulated devices driven by the world")
    add_view_option(parser)
    add_deprecated(parser, "--topics", "--record-topics", "record_topics")
    parser.set_defaults(handler="cli.run")


def _nodes(commands: Commands) -> None:
    parser = commands.add_parser(
        "nodes",
        help="list node implementations; `nodes IMPL`: its ports and parameters",
        description="List node implementations (optional inputs in [brackets]); "
        "with IMPL, show its ports and parameters with defaults, units and limits.",
    )
    parser.add_argument("impl", nargs="?", help="a registered name or module:Class")
    parser.set_defaults(handler="cli.nodes")


def _schema(commands: Commands) -> None:
    parser = commands.add_parser(
        "schema",
        help="print the JSON Schema of graph files (for an editor's YAML checking)",
        description="Print the JSON Schema of graph files, built from every node "
        "implementation's parameter declaration (docs/graphs.md).",
    )
    parser.add_argument("--out", type=Path, help="write it to OUT (default: print it)")
    parser.set_defaults(handler="cli.schema")


def _graph(commands: Commands) -> None:
    """``graph GRAPH --draw OUT`` (``cli.graphdraw``)."""
    parser = commands.add_parser(
        "graph",
        help="draw a graph file: its nodes and topics (SVG with Graphviz, or DOT/Mermaid text)",
        description="Draw a graph file after checking it: a box per node, an arrow per "
        "edge labelled with its topic and type.",
    )
    parser.add_argument("graph", type=Path, help="the graph file (YAML)")
    parser.add_argument(
        "--draw",
        type=Path,
        required=True,
        metavar="OUT",
        help="OUT.svg/.png/.pdf (Graphviz's dot; without it, DOT and Mermaid text beside), "
        "OUT.dot, OUT.mmd or OUT.md (Mermaid)",
    )
    parser.add_argument(
        "--set", dest="sets", action="append", default=[], metavar="NODE.PARAM=VALUE"
    )
    parser.add_argument("--swap", dest="swaps", action="append", default=[], metavar="NODE=IMPL")
    parser.add_argument("--only", default="", metavar="NODE,NODE", help="draw only these nodes")
    parser.set_defaults(handler="cli.graphdraw")


def _bag(commands: Commands) -> None:
    """``bag`` and its commands: these, and ``cli.bagview``'s (view, export, video)."""
    parser = commands.add_parser(
        "bag",
        help="bags: info|echo|diff|recover (docs/bags.md), view|export|video (docs/viewing.md)",
        description="Inspect, compare, repair and look at MCAP bags.",
    )
    sub = parser.add_subparsers(dest="bag_command", metavar="COMMAND", required=True)
    p_info = sub.add_parser("info", help="topics, types, counts, rates, duration, drops, graph")
    p_info.add_argument("file", type=Path)
    p_info.add_argument("--graph", action="store_true", help="also print the stored graph")
    p_echo = sub.add_parser("echo", help="print a topic's messages, arrays summarized")
    p_echo.add_argument("file", type=Path)
    p_echo.add_argument("--topic", required=True)
    p_echo.add_argument("--limit", type=int, default=None)
    p_echo.add_argument("--full", action="store_true", help="print arrays in full")
    p_echo.add_argument(
        "--strict", action="store_true", help="stop at a message that cannot be decoded"
    )
    p_recover = sub.add_parser("recover", help="rewrite a damaged or cut bag with a summary")
    p_recover.add_argument("file", type=Path)
    p_recover.add_argument("out", type=Path)
    p_diff = sub.add_parser("diff", help="per-message differences; exit 0 only when none")
    p_diff.add_argument("a", type=Path)
    p_diff.add_argument("b", type=Path)
    p_diff.add_argument("--topic", action="append", default=[], help="repeatable; default all")
    p_diff.add_argument("--rtol", type=float, default=1e-9)
    p_diff.add_argument("--atol", type=float, default=0.0)
    p_diff.add_argument(
        "--ignore", action="append", default=[], metavar="FIELD", help="e.g. header.stamp_nanos"
    )
    p_diff.add_argument("--max-lines", type=int, default=50)
    p_diff.add_argument(
        "--strict", action="store_true", help="stop at a message that cannot be decoded"
    )
    for each in (p_info, p_echo, p_recover, p_diff):
        each.set_defaults(handler="cli.bag")
    _bag_view(sub)


def _bag_view(bag_commands: Commands) -> None:
    """``bag view``, ``bag export`` and ``bag video`` (``cli.bagview``)."""
    for command, summary in BAG_VIEW.items():
        parser = bag_commands.add_parser(command, help=summary, description=summary)
        parser.add_argument("file", type=Path, help="the bag (MCAP)")
        parser.add_argument("--object", default="", help="object drawn under the estimated pose")
        if command == "view":
            parser.add_argument("--out", type=Path, default=None, metavar="FILE.rrd")
        elif command == "export":
            to = parser.add_mutually_exclusive_group(required=True)
            to.add_argument("--foxglove", type=Path, metavar="OUT.mcap", help="Foxglove's schemas")
            to.add_argument(
                "--ros2",
                type=Path,
                metavar="OUT_DIR",
                help="a ROS 2 bag (MCAP, CDR): standard messages, and the project's own",
            )
        else:
            parser.add_argument("--out", type=Path, required=True, metavar="FILE.mp4")
            parser.add_argument("--fps", type=float, default=0.0, help="0: the cameras' rate")
            parser.add_argument("--scale", type=int, default=2)
            parser.add_argument("--stills", type=Path, default=None, metavar="DIR")
        parser.set_defaults(handler="cli.bagview")


def _replay(commands: Commands) -> None:
    parser = commands.add_parser(
        "replay",
        help="replay a bag through its graph, some nodes swapped (docs/bags.md)",
        description="Replay a bag through its graph (or --graph), the nodes named in --swap "
        "and everything downstream of them live (see docs/bags.md).",
    )
    parser.add_argument("bag", type=Path)
    parser.add_argument("--graph", type=Path, default=None, help="graph file (default: the bag's)")
    add_run_options(
        parser,
        swap_metavar="NODE[=IMPL]",
        swap_help="run NODE live, with IMPL if given (repeatable)",
    )
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    parser.add_argument("--loop", action="store_true")
    parser.add_argument("--start", type=float, default=0.0, metavar="SECS")
    parser.add_argument("--end", type=float, default=None, metavar="SECS")
    parser.add_argument(
        "--replay-topics", default="", metavar="REGEX", help="the bag topics to replay"
    )
    parser.add_argument("--remap", action="append", default=[], metavar="BAG_TOPIC=TOPIC")
    parser.add_argument(
        "--strict", action="store_true", help="stop at a message that cannot be decoded"
    )
    parser.add_argument(
        "--no-hosts",
        action="store_true",
        help="drop the graph's hosts table: replay a bag recorded across hosts on this machine",
    )
    parser.add_argument("--print-graph", action="store_true", help="print the graph; run nothing")
    add_view_option(parser)
    add_deprecated(parser, "--replace", "--swap", "swaps", append=True)
    add_deprecated(parser, "--topics", "--replay-topics", "replay_topics")
    parser.set_defaults(handler="cli.replay")


def _topic(commands: Commands) -> None:
    """``topic list|echo|hz|nodes`` (``cli.topic``): look into a running graph."""
    parser = commands.add_parser(
        "topic",
        help="a running graph: its topics, their messages and rates, its nodes (docs/runtime.md)",
        description="Look into a running graph, read-only: its topics, a topic's messages "
        "and rate, its nodes.",
    )
    sub = parser.add_subparsers(dest="topic_command", metavar="COMMAND", required=True)
    run_help = "a run folder, launcher PID or graph name (default: the only running graph)"
    made = {
        "list": sub.add_parser("list", help="topics: type, rate, publisher, subscribers"),
        "echo": sub.add_parser("echo", help="print a topic's messages as `bag echo` does"),
        "hz": sub.add_parser("hz", help="a topic's rate, once a second"),
        "nodes": sub.add_parser("nodes", help="nodes: state, restarts, CPU seconds, drops"),
    }
    for name, each in made.items():
        each.add_argument("--run", default=None, metavar="RUN", help=run_help)
        each.add_argument(
            "--wait",
            type=float,
            default=0.0,
            metavar="SECS",
            help="wait up to SECS for the graph to be running (default: not at all)",
        )
        if name in ("echo", "hz"):
            each.add_argument("topic", help="node/output, as `topic list` names it")
        each.set_defaults(handler="cli.topic")
    made["echo"].add_argument("--limit", type=int, default=None, help="stop after N messages")
    made["echo"].add_argument("--full", action="store_true", help="print arrays in full")
    made["echo"].add_argument(
        "--timeout", type=float, default=10.0, metavar="SECS", help="stop after SECS without one"
    )
    pace = made["echo"].add_mutually_exclusive_group()
    pace.add_argument(
        "--max-hz",
        type=float,
        default=10.0,
        metavar="HZ",
        help="print a fresh message at most HZ times a second (default 10; between them the "
        "publisher sends this client nothing)",
    )
    pace.add_argument(
        "--every", action="store_true", help="print every message (costs a copy of each)"
    )
    made["hz"].add_argument("--secs", type=positive_secs, default=None, help="stop after SECS")
    made["hz"].add_argument("--window", type=int, default=1000, help="periods in the window")


def _batch(commands: Commands) -> None:
    from cli.batch import add_parser

    add_parser(commands)


def _keys(commands: Commands) -> None:
    parser = commands.add_parser(
        "keys",
        help="make or list the CURVE keys of a graph's hosts (docs/hosts.md)",
        description="Make or list the CURVE key pairs of a graph's hosts: the secret key "
        "stays in the key folder (mode 0600), the public key goes in the graph's hosts table.",
    )
    parser.add_argument("action", choices=("make", "list"))
    parser.add_argument("host", nargs="?", help="make: the host's name in the hosts table")
    parser.add_argument("--overwrite", action="store_true", help="make: replace a host's key")
    add_keys_option(parser)
    parser.set_defaults(handler="cli.keys", parser=parser)


def _calibrate(commands: Commands) -> None:
    parser = commands.add_parser(
        "calibrate",
        help="calibrate a rig: pressure zero, free bubble, intrinsics, camera mounts (docs/devices.md)",
        description="Calibrate a rig once, and after a bubble swap: the pressure sensors' "
        "zero, the free bubbles' statistics, the cameras' intrinsics and their mounts from "
        "grasps of a known cylinder. Writes the calibration file the hardware graph reads.",
    )
    parser.add_argument("--out", type=Path, required=True, help="the calibration file to write")
    parser.add_argument("--name", default="", help="the rig's name (default: the file's stem)")
    parser.add_argument("--address", default="192.168.1.20", help="the WSG 50's address")
    parser.add_argument("--port", type=int, default=1000, help="the WSG 50's TCP port")
    for side in ("left", "right"):
        parser.add_argument(
            f"--{side}-camera", default="", metavar="ID", help=f"the {side} camera's id"
        )
        parser.add_argument(
            f"--{side}-bridge", default="", metavar="SERIAL", help=f"the {side} bridge's serial"
        )
    parser.add_argument(
        "--use-case",
        default="MODE_9_5FPS_2000",
        help="the cameras' use case (the longest exposure: the least noise)",
    )
    parser.add_argument(
        "--radius-mm", type=float, default=30.0, help="the calibration cylinder's radius"
    )
    parser.add_argument("--grasps", type=int, default=6, help="how many grasps (3 to 6)")
    _add_emulate(parser, "calibrate the emulated rig (its lab places the cylinder)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing file")
    parser.set_defaults(handler="cli.calibrate", parser=parser)


def _add_emulate(parser: argparse.ArgumentParser, what: str) -> None:
    """``--emulate`` and ``--rig FILE`` (``sim.rig_launch``)."""
    parser.add_argument("--emulate", action="store_true", help=what)
    parser.add_argument(
        "--rig", default=None, metavar="FILE", help="with --emulate: an as-built rig (rigs/*.yaml)"
    )
