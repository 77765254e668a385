"""The bag command line: ``bag info|echo|diff|recover`` (see docs/bags.md; ``launch.py
replay`` is :mod:`runtime.replaygraph`).

python launch.py bag info FILE [--graph]
python launch.py bag recover FILE OUT
python launch.py bag echo FILE --topic T [--limit N] [--full] [--strict]
python launch.py bag diff A B [--topic T ...] [--rtol R] [--atol A] [--ignore FIELD ...] [--strict]

``bag diff`` pairs the messages of a topic by stamp and compares them field by field,
decoded from each bag's stored description, wall-clock fields left out
(:mod:`runtime.bag.diff`). It exits 0 when there is no difference, 1 when there is, 2 on
an error. ``bag echo`` and ``bag diff`` skip a message that cannot be decoded, say so and
go on (echo exits 1, diff counts it as a difference); ``--strict`` stops at it (exit 2).
"""

from __future__ import annotations

import argparse
import datetime
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cli.options import same_file
from messages.errors import BagError
from messages.files import load_yaml
from runtime.bag import BagReader, BagWriter
from runtime.bag.diff import diff_bags, summary

log = logging.getLogger(__name__)
SHOWN = 10  # skipped messages named one by one; the rest are counted

# -- shared formatting ---------------------------------------------------------------------------


def summarize_array(value: np.ndarray) -> str:
    """``float32[172x224] min .. max .. mean .. nan N`` for one array (what echo prints)."""
    shape = "x".join(str(n) for n in value.shape)
    text = f"{value.dtype}[{shape}]"
    if value.size == 0 or value.dtype.kind not in "biuf":
        return text
    data = value.astype(np.float64, copy=False)
    finite = data[np.isfinite(data)]
    if finite.size:
        text += f" min {finite.min():.6g} max {finite.max():.6g} mean {finite.mean():.6g}"
    nans = int(data.size - finite.size)
    if nans:
        text += f" non-finite {nans}"
    return text


def show_value(value: Any, full: bool) -> Any:
    """A decoded field as ``bag echo`` and ``topic echo`` print it: small arrays as lists,
    large ones summarized (all with ``full``)."""
    if isinstance(value, np.ndarray):
        if full or value.size <= 16:
            return value.tolist()
        return summarize_array(value)
    if isinstance(value, dict):
        return {k: show_value(v, full) for k, v in value.items()}
    if isinstance(value, list):
        return [show_value(v, full) for v in value]
    return value


def stamp_text(nanos: int) -> str:
    """A stamp as UTC date and time (wall clock) or seconds (scene time)."""
    if nanos > 10**17:  # a wall-clock stamp: show it as UTC
        when = datetime.datetime.fromtimestamp(nanos / 1e9, tz=datetime.UTC)
        return when.strftime("%Y-%m-%d %H:%M:%S.%f UTC")
    return f"{nanos / 1e9:.6f} s"


# -- info ----------------------------------------------------------------------------------------


def info_text(path: Path, *, show_graph: bool = False) -> str:
    """What ``bag info`` prints: file, duration, per-topic counts, rates, drops, the graph."""
    with BagReader(path, warn=lambda _: None) as reader:  # problems are listed below
        stats = reader.stats()
        drops = reader.drops()
        run = reader.run_info()
        lines = [f"file:      {path} ({path.stat().st_size / 1e6:.1f} MB)"]
        lines.append(
            "summary:   "
            + ("yes" if reader.has_summary else "NO (interrupted recording; recovered by scanning)")
        )
        counted = [s for s in stats.values() if s.messages]
        total = sum(s.messages for s in counted)
        if counted:
            start = min(s.first_log_nanos for s in counted)
            end = max(s.last_log_nanos for s in counted)
            lines.append(f"start:     {stamp_text(start)}")
            lines.append(f"end:       {stamp_text(end)}")
            lines.append(f"duration:  {(end - start) / 1e9:.3f} s")
        lines.append(f"messages:  {total}")
        if reader.lost_messages:
            more = ", and more in a cut or unreadable record" if reader.lost_unknown else ""
            lines.append(f"LOST:      {reader.lost_messages} message(s) in corrupt chunks{more}")
        elif reader.lost_unknown:
            lines.append("LOST:      the messages of a cut or unreadable record (count unknown)")
        if run:
            lines.append(f"recorded:  {run.get('command_line', '')}")
            if run.get("graph_source"):
                lines.append(f"graph:     {run['graph_source']}")
            graph_text = run.get("graph_yaml", "")
            if graph_text:
                nodes = _graph_nodes(graph_text)
                lines.append(
                    f"graph:     {len(nodes)} nodes ({', '.join(nodes)})"
                    + ("" if show_graph else "; `bag info --graph` prints it")
                )
        lines.append("")
        header = (
            f"{'topic':32} {'type':20} {'messages':>8} {'rate_hz':>8} {'MB':>8} "
            f"{'dropped':>7} {'seq_gaps':>8}"
        )
        lines.append(header)
        lines.append("-" * len(header))
        any_drop = False
        for topic in sorted(stats):
            s = stats[topic]
            d = drops.get(topic, {})
            dropped = d.get("runtime", 0) + d.get("rejected", 0)
            gaps = max(s.seq_gaps, d.get("seq_gaps", 0))
            any_drop |= bool(dropped or gaps)
            lines.append(
                f"{topic:32} {s.type_name:20} {s.messages:8d} {s.rate_hz:8.2f} "
                f"{s.bytes / 1e6:8.2f} {dropped:7d} {gaps:8d}"
            )
        if any_drop:
            lines.append("")
            lines.append("this recording DROPPED messages (see the dropped and seq_gaps columns)")
        if reader.problems:
            lines.append("")
            lines.extend(f"warning: {p}" for p in reader.problems)
        if show_graph and run.get("graph_yaml"):
            lines.append("")
            lines.append("# graph")
            lines.append(run["graph_yaml"].rstrip())
        return "\n".join(lines)


def _graph_nodes(text: str) -> list[str]:
    try:
        doc = load_yaml(text)
    except yaml.YAMLError:
        return []
    if isinstance(doc, dict) and isinstance(doc.get("nodes"), dict):
        return [str(n) for n in doc["nodes"]]
    return []


# -- echo ----------------------------------------------------------------------------------------


def echo_lines(
    path: Path,
    topic: str,
    *,
    limit: int | None = None,
    full: bool = False,
    strict: bool = False,
    skipped: list[str] | None = None,
) -> Iterator[str]:
    """Each message of ``topic``, decoded without project classes, arrays summarized.

    A message that cannot be decoded prints one ``SKIPPED`` line and is added to
    ``skipped``; with ``strict`` its :class:`BagError` ends the echo instead.
    """
    with BagReader(path) as reader:
        reader.require_topics([topic])
        for index, msg in enumerate(reader.messages([topic])):
            if limit is not None and index >= limit:
                return
            head = (
                f"--- {topic} #{index} {msg.channel.schema.type_name} seq {msg.sequence} "
                f"log {stamp_text(msg.log_time_nanos)} {msg.position()}"
            )
            try:
                fields = msg.decode_plain()
            except BagError as err:
                if strict:
                    raise
                if skipped is not None:
                    skipped.append(str(err))
                yield f"{head} SKIPPED, cannot decode: {err}"
                continue
            yield head
            for name, value in fields.items():
                yield f"{name}: {show_value(value, full)}"


# -- recover -------------------------------------------------------------------------------------


def recover(src: Path, dst: Path) -> tuple[int, list[str], list[str]]:
    """Copy every readable message of ``src`` into a complete bag ``dst`` (with a summary),
    past the ones that cannot be decoded.

    Returns:
        The number of messages copied, why each skipped message was skipped, and the
        problems met reading ``src``.

    Raises:
        BagError: ``dst`` is ``src`` (by any path: a link, the same inode).
    """
    if same_file(src, dst):
        raise BagError(f"{src}: recover writes a new file; give another output path")
    problems: list[str] = []
    skipped: list[str] = []
    with BagReader(src, warn=problems.append) as reader:
        copied = 0
        with BagWriter(dst) as writer:
            run = reader.run_info()
            if run:
                writer.add_metadata("softbubble.run", run)
            for msg in reader.messages():
                try:
                    msg.decode_plain()  # what cannot be decoded is not worth recovering
                    writer.copy_message(msg)
                except BagError as err:
                    skipped.append(str(err))
                    continue
                copied += 1
            old = reader.drops()
            writer.set_runtime_drops({t: d.get("runtime", 0) for t, d in old.items()})
            for topic, d in old.items():
                if topic in writer.counts:
                    writer.counts[topic].rejected = d.get("rejected", 0)
    return copied, skipped, problems


# -- bag main ------------------------------------------------------------------------------------


def main(args: argparse.Namespace) -> int:
    """``launch.py bag info|echo|diff|recover ...`` (exit code: 0 ok, 1 differences, 2 error)."""
    try:
        if args.bag_command == "info":
            print(info_text(args.file, show_graph=args.graph))
            return 0
        if args.bag_command == "recover":
            copied, lost, problems = recover(args.file, args.out)
            for problem in problems:
                print(f"warning: {problem}", file=sys.stderr)
            for why in lost[:SHOWN]:
                print(f"skipped: {why}", file=sys.stderr)
            print(f"{args.out}: {copied} message(s) recovered from {args.file}")
            if lost:
                print(
                    f"bag recover: {len(lost)} message(s) could not be decoded and were left out",
                    file=sys.stderr,
                )
            return 1 if lost else 0
        if args.bag_command == "echo":
            skipped: list[str] = []
            lines = echo_lines(
                args.file,
                args.topic,
                limit=args.limit,
                full=args.full,
                strict=args.strict,
                skipped=skipped,
            )
            for line in lines:
                print(line)
            if skipped:
                print(f"bag echo: {len(skipped)} message(s) could not be decoded", file=sys.stderr)
            return 1 if skipped else 0
        diffs = diff_bags(
            args.a,
            args.b,
            args.topic or None,
            rtol=args.rtol,
            atol=args.atol,
            ignore=args.ignore,
            strict=args.strict,
        )
    except BagError as err:
        print(f"bag {args.bag_command}: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    for d in diffs[: args.max_lines]:
        print(d)
    if len(diffs) > args.max_lines:
        print(f"... and {len(diffs) - args.max_lines} more")
    print(summary(diffs))
    return 1 if diffs else 0
