"""The bag command line: ``bag info|echo|diff`` and ``replay`` (see docs/bags.md).

python launch.py bag info FILE [--graph]
python launch.py bag recover FILE OUT
python launch.py bag echo FILE --topic T [--limit N] [--full] [--strict]
python launch.py bag diff A B [--topic T ...] [--rtol R] [--atol A] [--ignore FIELD ...] [--strict]
python launch.py replay FILE [--graph G] [--swap NODE[=IMPL] ...] [--rate X | --fast]
                        [--loop] [--start S] [--end E] [--replay-topics RE] [--remap A=B ...]
                        [--lockstep] [--strict] [--record OUT [--record-topics RE] [--overwrite]]
                        [--duration S]
                        [--set NODE.PARAM=VALUE ...] [--print-graph]

``bag diff`` compares messages of a topic in order, field by field, decoded from each bag's
stored description (no project classes needed); numbers and arrays with ``numpy.isclose``
tolerances (NaN equals NaN). It exits 0 when there is no difference, 1 when there is, 2 on
an error. ``bag echo`` and ``bag diff`` skip a message that cannot be decoded, say so and
go on (echo exits 1, diff counts it as a difference); ``--strict`` stops at it (exit 2).
``replay`` runs the graph stored in the bag (or ``--graph``) with the nodes named
in ``--swap`` (and everything downstream of them) live, and a ``replay`` node publishing
the recorded topics they need (see :func:`build_replay_graph`).
"""

from __future__ import annotations

import argparse
import copy
import datetime
import logging
import re
import shlex
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from messages.errors import BagError, GraphError
from runtime.bag import BagMessage, BagReader, BagWriter, topic_filter
from runtime.cli import add_deprecated, add_run_options

log = logging.getLogger(__name__)

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


def _show(value: Any, full: bool) -> Any:
    if isinstance(value, np.ndarray):
        if full or value.size <= 16:
            return value.tolist()
        return summarize_array(value)
    if isinstance(value, dict):
        return {k: _show(v, full) for k, v in value.items()}
    if isinstance(value, list):
        return [_show(v, full) for v in value]
    return value


def _stamp(nanos: int) -> str:
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
            lines.append(f"start:     {_stamp(start)}")
            lines.append(f"end:       {_stamp(end)}")
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
        doc = yaml.safe_load(text)
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
                f"log {_stamp(msg.log_time_nanos)} {msg.position()}"
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
                yield f"{name}: {_show(value, full)}"


# -- recover -------------------------------------------------------------------------------------


def recover(src: Path, dst: Path) -> tuple[int, list[str]]:
    """Copy every readable message of ``src`` into a complete bag ``dst`` (with a summary).

    Returns:
        The number of messages copied and the problems met reading ``src``.
    """
    if src.resolve() == dst.resolve():
        raise BagError(f"{src}: recover writes a new file; give another output path")
    problems: list[str] = []
    with BagReader(src, warn=problems.append) as reader:
        copied = 0
        with BagWriter(dst) as writer:
            run = reader.run_info()
            if run:
                writer.add_metadata("softbubble.run", run)
            for msg in reader.messages():
                writer.copy_message(msg)
                copied += 1
            old = reader.drops()
            writer.set_runtime_drops({t: d.get("runtime", 0) for t, d in old.items()})
            for topic, d in old.items():
                if topic in writer.counts:
                    writer.counts[topic].rejected = d.get("rejected", 0)
    return copied, problems


# -- diff ----------------------------------------------------------------------------------------


@dataclass
class Difference:
    topic: str
    index: int
    field: str
    detail: str

    def __str__(self) -> str:
        return f"{self.topic} #{self.index} {self.field}: {self.detail}"


def compare_values(
    a: Any,
    b: Any,
    *,
    rtol: float,
    atol: float,
    path: str = "",
    ignore: frozenset[str] = frozenset(),
) -> list[tuple[str, str]]:
    """Differences between two decoded values as ``(field path, what differs)``."""
    if path in ignore:
        return []
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[tuple[str, str]] = []
        for key in sorted(set(a) | set(b)):
            sub = f"{path}.{key}" if path else str(key)
            if sub in ignore:
                continue
            if key not in a or key not in b:
                out.append((sub, "only in " + ("B" if key not in a else "A")))
                continue
            out += compare_values(a[key], b[key], rtol=rtol, atol=atol, path=sub, ignore=ignore)
        return out
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        x, y = np.asarray(a), np.asarray(b)
        if x.shape != y.shape or x.dtype != y.dtype:
            return [(path, f"{x.dtype}{list(x.shape)} vs {y.dtype}{list(y.shape)}")]
        if x.dtype.kind in "biuf":
            close = np.isclose(x, y, rtol=rtol, atol=atol, equal_nan=True)
            if not close.all():
                diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
                worst = float(np.nanmax(np.where(close, 0.0, diff))) if diff.size else 0.0
                return [
                    (
                        path,
                        f"{int((~close).sum())} of {x.size} elements differ, max |a-b| {worst:.6g}",
                    )
                ]
            return []
        return [] if np.array_equal(x, y) else [(path, "arrays differ")]
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        if len(a) != len(b):
            return [(path, f"length {len(a)} vs {len(b)}")]
        out = []
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            out += compare_values(x, y, rtol=rtol, atol=atol, path=f"{path}[{i}]", ignore=ignore)
        return out
    numeric = (int, float)
    if isinstance(a, numeric) and isinstance(b, numeric) and not isinstance(a, bool | str):
        if isinstance(b, bool):
            return [] if a == b else [(path, f"{a!r} vs {b!r}")]
        if np.isclose(float(a), float(b), rtol=rtol, atol=atol, equal_nan=True):
            return []
        return [(path, f"{a!r} vs {b!r}")]
    return [] if a == b else [(path, f"{a!r} vs {b!r}")]


def diff_bags(
    path_a: Path,
    path_b: Path,
    topics: Sequence[str] | None = None,
    *,
    rtol: float = 1e-9,
    atol: float = 0.0,
    ignore: Sequence[str] = (),
    strict: bool = False,
) -> list[Difference]:
    """Per-message differences of the decoded fields of ``topics`` (default: every topic).

    A message that cannot be decoded on either side is one ``(undecodable)`` difference
    and the comparison goes on; with ``strict`` its :class:`BagError` ends the diff.
    """
    skip = frozenset(ignore)
    with BagReader(path_a) as ra, BagReader(path_b) as rb:
        if topics:
            ra.require_topics(topics)
            rb.require_topics(topics)
            chosen = list(topics)
        else:
            chosen = sorted(set(ra.topics()) | set(rb.topics()))
        out: list[Difference] = []
        for topic in chosen:
            msgs_a: list[BagMessage] = list(ra.messages([topic]))
            msgs_b: list[BagMessage] = list(rb.messages([topic]))
            if len(msgs_a) != len(msgs_b):
                out.append(
                    Difference(topic, -1, "(count)", f"{len(msgs_a)} vs {len(msgs_b)} messages")
                )
            for index, (ma, mb) in enumerate(zip(msgs_a, msgs_b, strict=False)):
                ta, tb = ma.channel.schema.type_name, mb.channel.schema.type_name
                if ta != tb:
                    out.append(Difference(topic, index, "(type)", f"{ta} vs {tb}"))
                    continue
                try:
                    plain_a = ma.decode_plain()
                    plain_b = mb.decode_plain()
                except BagError as err:
                    if strict:
                        raise
                    out.append(Difference(topic, index, "(undecodable)", str(err)))
                    continue
                found = compare_values(plain_a, plain_b, rtol=rtol, atol=atol, ignore=skip)
                out += [Difference(topic, index, name, detail) for name, detail in found]
        return out


# -- replay --------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class ReplayOptions:
    """How the replay node plays the bag (see :mod:`nodes.replay`)."""

    rate: float = 1.0
    fast: bool = False
    loop: bool = False
    start_secs: float = 0.0
    end_secs: float | None = None
    topics: str = ""
    remap: dict[str, str] = field(default_factory=dict)
    lockstep: bool = False
    strict: bool = False  # stop at a message that cannot be decoded (default: skip, count)

    def __post_init__(self) -> None:
        if self.rate <= 0:
            raise ValueError(f"rate must be > 0, got {self.rate}")
        if self.start_secs < 0:
            raise ValueError(f"start_secs must be >= 0, got {self.start_secs}")
        if self.end_secs is not None and self.end_secs <= self.start_secs:
            raise ValueError(
                f"end_secs must be > start_secs ({self.start_secs}), got {self.end_secs}"
            )
        for src, dst in self.remap.items():
            if "/" not in dst:
                raise ValueError(f"remap: {src!r} -> {dst!r}: a topic is 'node/output'")


def exact_topics(topics: Sequence[str]) -> str:
    """A ``topics`` pattern that selects exactly these topics."""
    return "^(?:" + "|".join(re.escape(t) for t in sorted(topics)) + ")$"


def _keep_known_params(name: str, body: dict[str, Any]) -> None:
    """Drop the parameters a swapped-in implementation does not take (they were the old one's)."""
    import dataclasses

    from runtime.registry import resolve

    try:
        cls = resolve(body["impl"])
    except KeyError:
        return  # the checker reports the unknown implementation
    known = {f.name for f in dataclasses.fields(cls.Params)}
    params = body.get("params") or {}
    dropped = sorted(set(params) - known)
    if dropped:
        log.warning(
            "replay: %s is now %s; dropping its old parameters %s", name, body["impl"], dropped
        )
        body["params"] = {k: v for k, v in params.items() if k in known}


def build_replay_graph(
    graph: Mapping[str, Any],
    bag_path: Path,
    swap: Mapping[str, str],
    options: ReplayOptions | None = None,
) -> dict[str, Any]:
    """The graph that replays ``bag_path`` through ``graph`` with some nodes swapped.

    The nodes named in ``swap`` get their new implementation (an empty string keeps
    theirs; parameters the new one does not take are dropped, with a warning) and run
    live, as does every node downstream of them, except one that also feeds back into
    their inputs (a loop through a simulated world): the replay stays open-loop there, with
    a warning. Every topic the live nodes read comes from a ``replay`` node if the bag has
    it; otherwise the node publishing it runs live too (and so on upstream). All other
    nodes, recorders included, are left out. The walk is the checked graph's
    (:meth:`runtime.graph.Graph.downstream` and ``upstream``).
    With nothing swapped, the replay node publishes every selected topic.

    Raises:
        GraphError: an unknown node in ``swap``, or a needed topic that is neither in
            the bag nor published by a node that can run.
        BagError: the bag cannot be read.
    """
    from runtime.graph import check  # the checker resolves node classes and their ports

    options = options or ReplayOptions()
    doc = copy.deepcopy(dict(graph))
    nodes: dict[str, Any] = doc.get("nodes") or {}
    for name, impl in swap.items():
        if name not in nodes:
            raise GraphError(
                f"{bag_path}: --swap {name}: the graph has no node {name!r} "
                f"(nodes: {', '.join(nodes)})"
            )
        if impl and impl != nodes[name].get("impl"):
            nodes[name]["impl"] = impl
            _keep_known_params(name, nodes[name])
    checked = check(doc, source=f"{bag_path} (replay graph)")
    recorders = {n for n, spec in checked.nodes.items() if spec.cls.raw_input}
    providers = checked.producers
    inputs = {n: [i.topic for i in spec.inputs.values()] for n, spec in checked.nodes.items()}
    swapped = set(swap)
    downstream = checked.downstream(swapped, skip=recorders) - swapped
    upstream = checked.upstream(swapped, skip=recorders) - swapped
    # A node both downstream and upstream of a swapped one closes a loop back into its
    # inputs (a supervisor commanding the simulated world that the cameras see): running
    # it live would make the world live too, so the replay stays open-loop there and that
    # node's topics come from the bag. Name it in --swap to run it live anyway.
    live = swapped | (downstream - upstream)
    direct = set().union(*(checked.feeds[n] for n in swapped)) - swapped
    for name in sorted(downstream & upstream & direct):
        log.warning(
            "replay: %s is downstream of %s but feeds back into its inputs; "
            "it does not rerun, its recorded topics stand (add --swap %s to run it live)",
            name,
            ", ".join(sorted(swapped)),
            name,
        )

    with BagReader(bag_path) as reader:
        bag_topics = list(reader.topics())
    chosen = topic_filter(options.topics)
    available = {options.remap.get(t, t): t for t in bag_topics if chosen(t)}

    while True:  # pull in live producers for topics the bag lacks, until nothing changes
        needed = {t: n for n in sorted(live) for t in inputs[n]}
        missing = [
            (t, n) for t, n in needed.items() if providers.get(t) not in live and t not in available
        ]
        if not missing:
            break
        for topic, reader_node in missing:
            maker = providers.get(topic)
            if maker is None or maker in recorders:
                raise GraphError(
                    f"{bag_path}: topic {topic!r} (read by {reader_node!r}) is neither in the "
                    f"bag nor published by a node of the graph"
                )
            live.add(maker)
    replayed = {t: available[t] for n in live for t in inputs[n] if providers.get(t) not in live}
    if not live:
        replayed = dict(available)
    if not replayed:
        raise GraphError(f"{bag_path}: nothing to replay: the live nodes read no recorded topic")

    out_nodes = {n: nodes[n] for n in nodes if n in live}
    name = "replay"
    while name in out_nodes:
        name += "_"
    bag_names = sorted(set(replayed.values()))
    params: dict[str, Any] = {
        "path": str(bag_path),
        "rate": options.rate,
        "fast": options.fast,
        "loop": options.loop,
        "start_secs": options.start_secs,
        "topics": exact_topics(bag_names),
        "remap": {bag: pub for pub, bag in replayed.items() if pub != bag},
        "lockstep": options.lockstep,
        "strict": options.strict,
    }
    if options.end_secs is not None:
        params["end_secs"] = options.end_secs
    out_nodes[name] = {"impl": "replay", "params": params, "required": True}
    result = {k: v for k, v in doc.items() if k != "nodes"}
    result["nodes"] = out_nodes
    return result


def _pairs(values: Sequence[str], flag: str, *, allow_bare: bool = False) -> dict[str, str]:
    out = {}
    for value in values:
        key, sep, rest = value.partition("=")
        if not key or (not sep and not allow_bare) or (sep and not rest):
            raise SystemExit(f"{flag} {value!r}: expected NAME=VALUE")
        out[key] = rest
    return out


def replay_main(argv: Sequence[str]) -> int:
    """``launch.py replay ...``: build the replay graph and run it (exit code)."""
    parser = argparse.ArgumentParser(
        prog="python launch.py replay",
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
    parser.add_argument("--print-graph", action="store_true", help="print the graph; run nothing")
    add_deprecated(parser, "--replace", "--swap", "swaps", append=True)
    add_deprecated(parser, "--topics", "--replay-topics", "replay_topics")
    args = parser.parse_args(list(argv))
    try:
        if args.graph is not None:
            from runtime.graph import load_document

            graph = load_document(args.graph)
        else:
            with BagReader(args.bag) as reader:
                text = reader.run_info().get("graph_yaml", "")
            if not text:
                print(f"{args.bag}: the bag stores no graph; pass --graph", file=sys.stderr)
                return 2
            graph = yaml.safe_load(text)
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
    except (BagError, GraphError, ValueError) as err:
        print(f"replay: {err}", file=sys.stderr)
        return 2
    if args.print_graph:
        print(yaml.safe_dump(replay_graph, sort_keys=False), end="")
        return 0
    from runtime.launcher import launch

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
        command_line=shlex.join([sys.executable, "launch.py", "replay", *argv]),
    )


# -- bag main ------------------------------------------------------------------------------------


def main(argv: Sequence[str]) -> int:
    """``launch.py bag info|echo|diff ...`` (exit code: 0 ok, 1 differences, 2 error)."""
    parser = argparse.ArgumentParser(prog="python launch.py bag", description="Inspect MCAP bags.")
    sub = parser.add_subparsers(dest="command", required=True)
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
    args = parser.parse_args(list(argv))
    try:
        if args.command == "info":
            print(info_text(args.file, show_graph=args.graph))
            return 0
        if args.command == "recover":
            copied, problems = recover(args.file, args.out)
            for problem in problems:
                print(f"warning: {problem}", file=sys.stderr)
            print(f"{args.out}: {copied} message(s) recovered from {args.file}")
            return 0
        if args.command == "echo":
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
        print(f"bag {args.command}: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    for d in diffs[: args.max_lines]:
        print(d)
    if len(diffs) > args.max_lines:
        print(f"... and {len(diffs) - args.max_lines} more")
    messages = len({(d.topic, d.index) for d in diffs})
    print(f"{len(diffs)} difference(s) in {messages} message(s)" if diffs else "no differences")
    return 1 if diffs else 0
