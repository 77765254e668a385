"""``launch.py nodes [IMPL]``: the node implementations, or one's ports and parameters."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from runtime.node import Node
# The registry, node and params modules import messages (numpy, msgspec): only this
# command imports them, when it runs, so ``launch.py --help`` stays light.


def main(args: argparse.Namespace) -> int:
    import nodes
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

    Types, limits, choices and help are read from the parameter class's declaration
    (``runtime.params``); a check across fields (``max_depth_m > min_depth_m``) is the
    class's own and not listed. Nested parameters are listed by their dotted path, as
    ``--set`` takes them.

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
