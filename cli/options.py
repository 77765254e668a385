"""The options that running a graph and replaying a bag share, declared once.

One vocabulary for both: ``--swap NODE=IMPL`` changes an implementation, ``--set
NODE.PARAM=VALUE`` a parameter (``PARAM`` may be dotted: ``shear.farneback.winsize``),
``--record OUT.mcap`` with ``--record-topics REGEX`` records, ``--replay-topics REGEX``
(replay only) chooses what the bag plays, ``--host NAME`` (``--keys DIR``) runs one host's
part of a graph with a hosts table. Old spellings (``--replace``, ``--topics``)
still work for a while and say what replaced them.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


class _Deprecated(argparse.Action):
    """Stores into the new option's destination and warns once on stderr."""

    def __init__(self, *args: Any, new: str, append: bool, **kwargs: Any) -> None:
        self.new = new
        self.append = append
        super().__init__(*args, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        print(f"warning: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        if self.append:
            setattr(namespace, self.dest, [*getattr(namespace, self.dest), values])
        else:
            setattr(namespace, self.dest, values)


def add_deprecated(
    parser: argparse.ArgumentParser, old: str, new: str, dest: str, *, append: bool = False
) -> None:
    """Accept ``old`` as a hidden alias of ``new`` (stored in ``dest``), with a warning."""
    parser.add_argument(
        old, dest=dest, action=_Deprecated, new=new, append=append, help=argparse.SUPPRESS
    )


def add_graph_changes(
    parser: argparse.ArgumentParser, *, swap_help: str, swap_metavar: str
) -> None:
    """``--set NODE.PARAM=VALUE`` and ``--swap``: the changes to a graph every command that
    runs one takes (run, replay, batch)."""
    parser.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="NODE.PARAM=VALUE",
        help="set a parameter (repeatable; PARAM may be dotted: shear.farneback.winsize=45)",
    )
    parser.add_argument(
        "--swap", dest="swaps", action="append", default=[], metavar=swap_metavar, help=swap_help
    )


def add_run_options(parser: argparse.ArgumentParser, *, swap_help: str, swap_metavar: str) -> None:
    """``--set``, ``--swap``, ``--record``, ``--record-topics``, ``--overwrite``, ``--lockstep``,
    ``--duration``, ``--log-level``, ``--host`` and ``--keys``, as ``launch.py GRAPH`` and
    ``launch.py replay`` take them.
    """
    add_graph_changes(parser, swap_help=swap_help, swap_metavar=swap_metavar)
    parser.add_argument("--record", type=Path, default=None, metavar="OUT.mcap")
    parser.add_argument(
        "--record-topics",
        default=None,
        metavar="REGEX",
        help="with --record: the topics to keep (re.search; default all)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="with --record: replace a finished bag"
    )
    parser.add_argument(
        "--lockstep",
        action="store_true",
        help="deterministic: a replay waits for the graph to be idle where order matters",
    )
    parser.add_argument(
        "--duration",
        type=positive_secs,
        default=None,
        metavar="SECS",
        help="stop after this many seconds (> 0)",
    )
    parser.add_argument("--log-level", default="INFO", choices=LOG_LEVELS)
    parser.add_argument(
        "--host",
        default=None,
        metavar="NAME",
        help="with a hosts table: run this host's nodes only (docs/hosts.md)",
    )
    add_keys_option(parser)


def add_view_option(parser: argparse.ArgumentParser) -> None:
    """``--view [OUT.rrd | foxglove]``, as ``run`` and ``replay`` take it."""
    parser.add_argument(
        "--view",
        nargs="?",
        const="spawn",
        default=None,
        metavar="OUT.rrd|foxglove",
        help="add a viewer: a Rerun window, an .rrd file, or a Foxglove live server",
    )


def positive_secs(text: str) -> float:
    """A finite number of seconds > 0 (argparse ``type``)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}")
    return value


def add_keys_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--keys",
        type=Path,
        default=None,
        metavar="DIR",
        help="the hosts' key folder (default ~/.config/softbubble/keys)",
    )


HOST_OPTIONS = ("--host", "--keys")


def shared_command_line(argv: Sequence[str]) -> str:
    """``argv`` (``launch.py ...``) as every host of a graph runs it, to record and compare:
    without ``--host`` and ``--keys``, which differ from host to host, and, if it had
    them, with ``python`` for the interpreter, whose path may differ too."""
    kept: list[str] = []
    skip = False
    for word in argv:
        if skip:
            skip = False
        elif word in HOST_OPTIONS:
            skip = True
        elif not word.startswith(tuple(f"{o}=" for o in HOST_OPTIONS)):
            kept.append(word)
    python = sys.executable if len(kept) == len(argv) else "python"
    return shlex.join([python, *kept])


def same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (through links, or the same inode), so a command
    never writes onto what it reads."""
    try:
        return a.resolve() == b.resolve() or os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): not the same file
        return False
