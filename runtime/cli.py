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
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from runtime.node import Node
# The registry, node and params modules import messages (numpy, msgspec): only the
# commands that list nodes import them, so ``launch.py --help`` stays light.

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


def add_run_options(parser: argparse.ArgumentParser, *, swap_help: str, swap_metavar: str) -> None:
    """``--set``, ``--swap``, ``--record``, ``--record-topics``, ``--overwrite``, ``--lockstep``,
    ``--duration``, ``--log-level``, ``--host`` and ``--keys``, as ``launch.py GRAPH`` and
    ``launch.py replay`` take them.
    """
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


def flags_differ(theirs: str, ours: str) -> tuple[str, str]:
    """The options (with their values) in one command line and not in the other, each way."""

    def options(argv: str) -> list[str]:
        try:
            words = shlex.split(argv)
        except ValueError:  # unbalanced quotes: the words as they are
            words = argv.split()
        out: list[str] = []
        for i, word in enumerate(words):
            if word.startswith("--"):
                value = words[i + 1] if i + 1 < len(words) else ""
                out.append(word if value.startswith("--") or not value else f"{word} {value}")
        return out

    mine, other = options(ours), options(theirs)
    return (
        " ".join(o for o in other if o not in mine),
        " ".join(o for o in mine if o not in other),
    )


# -- launch.py nodes ------------------------------------------------------------------------------


def _ports(cls: type[Node]) -> tuple[str, str]:
    ins = ", ".join(
        f"[{p}]:{t.__name__}" if p in cls.optional_inputs else f"{p}:{t.__name__}"
        for p, t in cls.inputs.items()
    )
    outs = ", ".join(f"{p}:{t.__name__}" for p, t in cls.outputs.items())
    if cls.raw_input:
        ins = "any topic, any type"
    return ins or "-", outs or "-"


def _clip(text: str, width: int = 40) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."


def node_table(names: Sequence[str]) -> str:
    """One line per implementation: its inputs (optional ones in brackets) and outputs."""
    from runtime.registry import resolve

    lines = []
    for name in names:
        ins, outs = _ports(resolve(name))
        lines.append(f"{name:32} in: {ins}  out: {outs}")
    lines.append("")
    lines.append("[port]: an optional input. `launch.py nodes IMPL` shows one's parameters.")
    return "\n".join(lines)


def node_details(impl: str) -> str:
    """An implementation's ports and every parameter: type, default, unit, limits, meaning.

    Limits are those the parameter class's own check states (found by building it with
    far-out values); a class whose check needs another parameter first (a required path)
    shows none. Nested parameters are listed by their dotted path, as ``--set`` takes them.

    Raises:
        KeyError: an unknown implementation (the message lists the valid ones).
    """
    from runtime.params import describe
    from runtime.registry import class_path, resolve

    cls = resolve(impl)
    ins, outs = _ports(cls)
    summary = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())  # 1st paragraph
    lines = [f"{impl}  ({class_path(cls)})"]
    if summary:
        lines.append(f"  {summary}")
    lines += [f"  inputs:  {ins}", f"  outputs: {outs}", ""]
    params = describe(cls.Params)
    if not params:
        lines.append("  no parameters")
        return "\n".join(lines)
    rows = [["param", "type", "default", "unit"]]
    rows += [[p.path, p.type, _clip(repr(p.default)), p.unit or "-"] for p in params]
    limits = ["limits"] + ["; ".join(p.limits) or "-" for p in params]
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for row, limit in zip(rows, limits, strict=True):
        cells = "  ".join(f"{cell:{w}}" for cell, w in zip(row, widths, strict=True))
        lines.append(f"  {cells}  {limit}")
    documented = [p for p in params if p.doc]
    if documented:
        lines.append("")
        lines += [f"  {p.path}: {p.doc}" for p in documented]
    return "\n".join(lines)
