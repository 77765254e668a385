"""``launch.py topic list|echo|hz|nodes``: look into a running graph, read-only.

    python launch.py topic list [--run RUN]            topics: type, rate, publisher, subscribers
    python launch.py topic echo TOPIC [--run RUN] [--limit N] [--full] [--max-hz HZ | --every]
    python launch.py topic hz TOPIC [--run RUN] [--secs S] [--window N]
    python launch.py topic nodes [--run RUN]           nodes: state, restarts, CPU, drops

``RUN`` is a run folder, a launcher PID or a graph name (``graph`` for graph.yaml);
without it, the only running graph. The graph is found through its launcher's
``status.json`` (:mod:`runtime.status`); ``echo`` and ``hz`` tap the topic
(:mod:`runtime.introspect`). See docs/runtime.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from cli.bag import show_value, stamp_text
from messages.errors import FrameDecodeError, GraphError
from runtime.introspect import Rate, Tap, decode_message, plain_fields
from runtime.status import Run, pick_run


def list_text(run: Run) -> str:
    """The topics of a run: type, mean rate since the start, messages, publisher, subscribers."""
    st = run.status
    elapsed = max(float(st.get("elapsed_secs", 0.0)), 1e-9)
    lines = [f"{st.get('source')} (pid {st.get('pid')}, running {elapsed:.1f} s, {run.rundir})"]
    header = f"{'topic':32} {'type':18} {'rate_hz':>8} {'messages':>9} {'dropped':>7}  publisher -> subscribers"
    lines += [header, "-" * len(header)]
    for topic, t in sorted(st.get("topics", {}).items()):
        subscribers = ", ".join(t["subscribers"]) or "-"
        lines.append(
            f"{topic:32} {t['type']:18} {t['messages'] / elapsed:8.1f} {t['messages']:9d} "
            f"{t['dropped']:7d}  {t['publisher']} -> {subscribers}"
        )
    return "\n".join(lines)


def nodes_text(run: Run) -> str:
    """The nodes of a run: state, restarts, CPU seconds, messages dropped at their inputs."""
    st = run.status
    lines = [f"{st.get('source')} (pid {st.get('pid')}, running {st.get('elapsed_secs', 0):.1f} s)"]
    header = f"{'node':28} {'state':16} {'restarts':>8} {'cpu_secs':>9} {'dropped':>8} {'pid':>8}"
    lines += [header, "-" * len(header)]
    for name, n in sorted(st.get("nodes", {}).items()):
        lines.append(
            f"{name:28} {n['state']:16} {n['restarts']:8d} {n['cpu_secs']:9.2f} "
            f"{n['dropped']:8d} {n['pid'] or '-':>8}"
        )
    return "\n".join(lines)


def tap(run: Run, topic: str) -> Tap:
    return Tap(run.endpoint(topic), topic, others=run.status.get("topics", {}))


def echo(
    run: Run,
    topic: str,
    *,
    limit: int | None,
    full: bool,
    timeout_secs: float,
    max_hz: float | None,
) -> int:
    """Print messages of ``topic`` as ``bag echo`` does: every one (``max_hz`` None), or a
    fresh one at most ``max_hz`` times a second; returns how many."""
    shown = 0
    type_name = run.status["topics"][topic]["type"]
    due = time.monotonic()
    with tap(run, topic) as source:
        while limit is None or shown < limit:
            if max_hz is None:
                frames = source.receive(timeout_secs)
            else:
                time.sleep(max(0.0, due - time.monotonic()))
                due = time.monotonic() + 1.0 / max_hz
                frames = source.sample(timeout_secs)
            if frames is None:
                break
            try:
                msg = decode_message(frames)
            except FrameDecodeError as err:
                print(f"--- {topic} #{shown} {type_name} SKIPPED, cannot decode: {err}")
                shown += 1
                continue
            header = getattr(msg, "header", None)
            seq = getattr(header, "seq", "-")
            stamp = stamp_text(int(getattr(header, "stamp_nanos", 0)))
            print(f"--- {topic} #{shown} {type(msg).__name__} seq {seq} stamp {stamp}")
            for name, value in plain_fields(msg).items():
                print(f"{name}: {show_value(value, full)}")
            shown += 1
    return shown


def hz(run: Run, topic: str, *, secs: float | None, window: int) -> dict[str, float] | None:
    """Print ``topic``'s rate once a second (for ``secs``, or until Ctrl-C); the last one."""
    rate = Rate(window=window)
    start = time.monotonic()
    printed = start
    last: dict[str, float] | None = None
    with tap(run, topic) as source:
        while secs is None or time.monotonic() - start < secs:
            left = 0.2 if secs is None else min(0.2, max(0.0, secs - (time.monotonic() - start)))
            if (frames := source.receive(left)) is not None:
                rate.add(time.monotonic(), _stamp_and_seq(frames))
            now = time.monotonic()
            if now - printed >= 1.0:
                printed = now
                last = rate.summary() or last
                print(_rate_line(topic, last, rate.count), flush=True)
    last = rate.summary()
    print(_rate_line(topic, last, rate.count))
    return last


def _stamp_and_seq(frames: list[Any]) -> tuple[int, int] | None:
    """The message's ``(header.stamp_nanos, header.seq)``; None without a header (or for
    a frame that does not decode: it still arrived)."""
    try:
        header = getattr(decode_message(frames), "header", None)
    except FrameDecodeError:
        return None
    return None if header is None else (header.stamp_nanos, header.seq)


def _rate_line(topic: str, summary: dict[str, float] | None, count: int) -> str:
    if summary is None:
        return f"{topic}: {count} message(s), no rate yet"
    line = (
        f"{topic}: rate {summary['rate_hz']:.2f} Hz  min {summary['min_secs']:.4f} s  "
        f"max {summary['max_secs']:.4f} s  std {summary['std_secs']:.4f} s  "
        f"window {int(summary['periods'])}  ({count} messages)"
    )
    if "stamp_rate_hz" in summary:
        line += (
            f"  stamps {summary['stamp_rate_hz']:.2f} Hz"
            f"  seq {int(summary['first_seq'])}-{int(summary['last_seq'])}"
        )
    return line


def main(args: argparse.Namespace) -> int:
    """``launch.py topic COMMAND ...``: 0, or 1 when echo/hz saw nothing, 2 on an error."""
    try:
        run = pick_run(args.run, wait_secs=args.wait)
        if args.topic_command == "list":
            print(list_text(run))
        elif args.topic_command == "nodes":
            print(nodes_text(run))
        elif args.topic_command == "echo":
            run.endpoint(args.topic)
            shown = echo(
                run,
                args.topic,
                limit=args.limit,
                full=args.full,
                timeout_secs=args.timeout,
                max_hz=None if args.every else args.max_hz,
            )
            return 0 if shown else 1
        else:
            run.endpoint(args.topic)
            return 0 if hz(run, args.topic, secs=args.secs, window=args.window) else 1
    except GraphError as err:
        print(f"topic {args.topic_command}: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    return 0
