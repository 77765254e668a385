"""Lockstep replay across hosts: one host against the same graph split over two.

A bag of ``messages`` Ticks on two topics, alternating, replayed in lockstep (``--lockstep``,
as fast as the barrier allows) through a relay and a merge of the relay's output with the
other topic, recorded with ``--record``. The merge reads two publishers, so the replay
waits for the whole graph to be idle before every message. Rows (``mode``):

``one_host``     one launcher (the graph without its hosts table), every socket ``ipc``;
``two_hosts``    two launchers, ``--host a`` and ``--host b``, on two port ranges of this
                 machine's loopback: the replay, the merge and the recorder on ``a``, the
                 relay on ``b``, so every message of one topic goes a -> b -> a, and the
                 idle barrier waits for ``b``'s counts over the launchers' link.

``msgs_per_sec``: merged messages over the recorder's first to last receive time (the
median of ``repeats`` runs, alternating the modes); ``vs_one_host``: the median ratio of
each two-host run to the one-host run next to it. On one machine this is the cost of the
barrier's extra hop through the link (no network); across machines add the round trip.

    python -m bench.hosts [--quick] [--json]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

from bench.common import Row, launcher_log, main, median, progress
from messages import Header, Tick
from runtime.bag import BagReader, BagWriter
from runtime.hosts import without_hosts
from runtime.node import Node

MODES = ("one_host", "two_hosts")
ROOT = Path(__file__).resolve().parents[1]


class TickRelay(Node):
    """Forwards each tick (a hop to the other host and back)."""

    inputs = {"tick": Tick}
    outputs = {"tick": Tick}

    def on_tick(self, msg: Tick) -> None:
        self.io.publish("tick", msg)


class TickMerge(Node):
    """Fan-in of two publishers: the replay's lockstep waits for idle before each message."""

    inputs = {"a": Tick, "b": Tick}
    outputs = {"tick": Tick}

    def on_a(self, msg: Tick) -> None:
        self.io.publish("tick", msg)

    def on_b(self, msg: Tick) -> None:
        self.io.publish("tick", msg)


def graph(bag: Path) -> dict[str, Any]:
    here = "bench.hosts"  # not __name__: __main__ under python -m
    return {
        "hosts": {
            "a": {"address": "127.0.0.1", "ports": [24400, 24419]},
            "b": {"address": "127.0.0.1", "ports": [24420, 24439]},
        },
        "nodes": {
            "replay": {
                "impl": "replay",
                "host": "a",
                "params": {"path": str(bag), "lockstep": True},
            },
            "relay": {
                "impl": f"{here}:TickRelay",
                "host": "b",
                "inputs": {"tick": "source_a/tick"},
            },
            "merge": {
                "impl": f"{here}:TickMerge",
                "host": "a",
                "inputs": {"a": "relay/tick", "b": "source_b/tick"},
            },
        },
    }


def make_bag(path: Path, messages: int) -> None:
    with BagWriter(path) as writer:
        for i in range(messages):
            topic = ("source_a/tick", "source_b/tick")[i % 2]
            msg = Tick(header=Header(stamp_nanos=i, seq=i // 2), value=float(i))
            writer.write_message(topic, msg, log_time_nanos=i * 1_000_000)


def run_once(mode: str, bag: Path, workdir: Path) -> tuple[int, float]:
    """Merged messages and their rate (messages/s) of one lockstep replay."""
    doc = graph(bag)
    hosts: tuple[str | None, ...] = ("a", "b") if mode == "two_hosts" else (None,)
    if mode == "one_host":
        doc = without_hosts(doc)
    path = workdir / f"{mode}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = workdir / f"{mode}.mcap"
    argv = [sys.executable, "launch.py", str(path), "--lockstep", "--log-level", "WARNING"]
    argv += ["--record", str(out), "--record-topics", "^merge/tick$", "--overwrite"]
    with launcher_log("hosts") as log:
        procs = [
            subprocess.Popen(argv + (["--host", h] if h else []), cwd=ROOT, stdout=log, stderr=log)
            for h in hosts
        ]
        codes = [p.wait(timeout=600) for p in procs]
    if any(codes):
        raise RuntimeError(f"{mode}: the launchers exited {codes} (see bench/results/hosts.log)")
    with BagReader(out) as reader:
        stats = reader.stats()["merge/tick"]
    secs = (stats.last_log_nanos - stats.first_log_nanos) / 1e9
    return stats.messages, (stats.messages - 1) / secs


def run(quick: bool) -> list[Row]:
    messages, repeats = (200, 1) if quick else (2000, 3)
    runs: dict[str, list[float]] = {m: [] for m in MODES}
    counts: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="bench-hosts-") as tmp:
        workdir = Path(tmp)
        bag = workdir / "ticks.mcap"
        make_bag(bag, messages)
        points = [(r, m) for r in range(repeats) for m in (MODES if r % 2 == 0 else MODES[::-1])]
        for _, mode in progress(points, "bench.hosts", label="repeat {0[0]} {0[1]}".format):
            counts[mode], rate = run_once(mode, bag, workdir)
            runs[mode].append(rate)
    one = runs["one_host"]
    return [
        {
            "mode": mode,
            "messages": counts[mode],
            "repeats": repeats,
            "msgs_per_sec": median(runs[mode]),
            "vs_one_host": median([r / o for r, o in zip(runs[mode], one, strict=True)]),
        }
        for mode in MODES
    ]


if __name__ == "__main__":
    main("hosts", run, columns=["mode", "messages", "repeats", "msgs_per_sec", "vs_one_host"])
