"""What a node counts per input, and the launcher's end-of-run table made of it.

:class:`InputCounters` live in each node process (``runtime.runner``), which reports
them with every heartbeat. The table, per topic: messages published, the rate, and what
its subscribers lost (``dropped``), skipped on purpose (``superseded``), could not
decode (``bad``), and how many its publisher sent with a NaN or infinity where the type
says a number is finite (``nonfinite``, counted once per message where it is published).
Per node: restarts, CPU seconds, the last exit code.

``dropped`` is what the receivers counted from sequence gaps, but never more than what
the publisher sent and the receiver did not take off its socket: a corrupted
``header.seq`` cannot make a topic lose more messages than it carried, and a frame that
arrived but did not decode is ``bad``, not also dropped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from runtime.protocol import INPUT_COUNTERS


@dataclass
class InputCounters:
    """One input's counts; the names match ``protocol.INPUT_COUNTERS``."""

    received: int = 0  # every message taken off the socket, superseded ones included
    dropped: int = 0
    superseded: int = 0
    bad_frames: int = 0
    last_seq: int | None = None
    unseq: int = 0  # frames since ``last_seq`` that may hold a seq of their own: bad ones
    suspect: tuple[int, int] | None = None  # (seq, unseq) of a message off the sequence

    def note_seq(self, seq: int, skipped: int = 0) -> None:
        """Count the messages lost before one with ``header.seq == seq``.

        ``skipped`` superseded messages and the bad frames since the last message may
        each fill one number of a gap. A seq off the sequence (a gap, or back to 0 after
        the publisher restarted) is held as a suspect until the next message: if that one
        follows the old sequence, the suspect was a corrupted seq and costs nothing;
        otherwise its gap is counted and the sequence goes on from it.
        """
        unseq = self.unseq + skipped
        self.unseq = 0
        if self.suspect is not None:
            wild, wild_unseq = self.suspect
            self.suspect = None
            last = self.last_seq if self.last_seq is not None else wild
            if last < seq <= last + 2 + wild_unseq + unseq:
                self.last_seq = seq
                return
            if wild > last:
                self.dropped += max(0, wild - last - 1 - wild_unseq)
            self.last_seq = wild
        if self.last_seq is None or self.last_seq < seq <= self.last_seq + 1 + unseq:
            self.last_seq = seq
        else:
            self.suspect = (seq, unseq)

    def gaps(self) -> int:
        """``dropped``, and the gap before a message still held as a suspect (the last
        message of a run is followed by none that could confirm it)."""
        if self.suspect is None or self.last_seq is None:
            return self.dropped
        wild, wild_unseq = self.suspect
        return self.dropped + max(0, wild - self.last_seq - 1 - wild_unseq)


def delivered(
    edges: Iterable[tuple[str, str, str]],
    published: Mapping[str, int],
    received: Callable[[str, str], int | None],
) -> bool:
    """Whether each edge ``(topic, node, port)`` received all ``published[topic]`` messages
    (``received(node, port)``; an edge it answers None for is not counted)."""
    for topic, node, port in edges:
        got = received(node, port)
        if got is not None and got < published.get(topic, 0):
            return False
    return True


def balanced(
    edges: Iterable[tuple[str, str, str]],
    stats: Mapping[str, dict[str, Any]],
    published: Mapping[str, int] | None = None,
) -> bool:
    """Whether, by the nodes' heartbeat ``stats``, each edge to one of them received
    everything published on it (by ``published``, default: by the publishers among them;
    an edge to a node without stats is not counted)."""
    if published is None:
        published = {t: n for st in stats.values() for t, n in st.get("published", {}).items()}

    def received(node: str, port: str) -> int | None:
        st = stats.get(node)
        return None if st is None else st.get("inputs", {}).get(port, {}).get("received", 0)

    return delivered(edges, published, received)


def add_stats(base: dict[str, Any], more: dict[str, Any]) -> dict[str, Any]:
    """Sum two stats snapshots (of two incarnations of one node)."""
    if not base:
        return dict(more)
    if not more:
        return dict(base)
    published = dict(base.get("published", {}))
    for topic, count in more.get("published", {}).items():
        published[topic] = published.get(topic, 0) + count
    inputs = {port: dict(v) for port, v in base.get("inputs", {}).items()}
    for port, v in more.get("inputs", {}).items():
        if port in inputs:
            for key in INPUT_COUNTERS:
                inputs[port][key] = inputs[port].get(key, 0) + v.get(key, 0)
        else:
            inputs[port] = dict(v)
    return {"published": published, "inputs": inputs}


_EDGE_COLUMNS = ("delivered", "dropped", "unreceived", "superseded", "bad_frames")
_LIVE_COLUMNS = ("messages", "dropped", "superseded", "bad_frames", "nonfinite")


def edge_rows(stats: dict[str, dict[str, Any]]) -> dict[str, dict[str, int]]:
    """One row per edge (``topic -> node.port``), and per topic no node here reads.

    Every message published on a topic is in exactly one column of each edge reading it:
    ``messages`` = ``delivered`` (handed to the node) + ``dropped`` (sequence gaps: lost at
    a high-water mark before a message the subscriber did receive) + ``unreceived``
    (published, never taken off the subscriber's socket: still queued when the run
    stopped, or lost at a high-water mark after its last message) + ``superseded``
    (skipped on purpose by a ``latest`` input) + ``bad_frames`` (could not be decoded).
    ``nonfinite`` counts the topic's messages published with a NaN or infinity where the
    type says finite (the publisher checks each once), not a loss. A topic
    published on another host: ``messages`` is what arrived here, so nothing is unreceived,
    and its ``nonfinite`` is in that host's table (its publisher counted them).
    """
    published: dict[str, int] = {}
    nonfinite: dict[str, int] = {}
    for node_stats in stats.values():
        for topic, count in node_stats.get("published", {}).items():
            published[topic] = published.get(topic, 0) + count
        for topic, count in node_stats.get("nonfinite", {}).items():
            nonfinite[topic] = nonfinite.get(topic, 0) + count
    rows: dict[str, dict[str, int]] = {}
    read: set[str] = set()
    for node in sorted(stats):
        for port, inp in sorted(stats[node].get("inputs", {}).items()):
            topic, received = inp["topic"], inp["received"]
            read.add(topic)
            sent = published.get(topic, received)  # elsewhere: what came here
            sent = max(sent, received)  # a publisher whose final counts never came
            lost = sent - received
            dropped = min(inp["dropped"], lost)  # never more than it did not take
            taken = inp["superseded"] + inp["bad_frames"]
            rows[f"{topic} -> {node}.{port}"] = {
                "messages": sent,
                "delivered": max(0, received - taken),
                "dropped": dropped,
                "unreceived": lost - dropped,
                "superseded": inp["superseded"],
                "bad_frames": inp["bad_frames"],
                "nonfinite": nonfinite.get(topic, 0),
            }
    for topic, count in published.items():
        if topic not in read:
            none = dict.fromkeys(_EDGE_COLUMNS, 0)
            rows[f"{topic} (no reader here)"] = {
                **none,
                "messages": count,
                "nonfinite": nonfinite.get(topic, 0),
            }
    return rows


def topic_totals(stats: dict[str, dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per topic, for a live view (``runtime.status``): messages published (on another
    host: the most any edge here received), its ``nonfinite`` and its edges' ``dropped``,
    ``superseded`` and ``bad_frames`` summed; ``unreceived`` is left out, as in a running
    graph it is mostly in flight."""
    out: dict[str, dict[str, int]] = {}
    for name, row in edge_rows(stats).items():
        total = out.setdefault(name.split(" ", 1)[0], dict.fromkeys(_LIVE_COLUMNS, 0))
        for key in _LIVE_COLUMNS:
            if key in ("messages", "nonfinite"):  # the topic's own, in every edge's row
                total[key] = max(total[key], row[key])
            else:
                total[key] += row[key]
    return out


def table(
    stats: dict[str, dict[str, Any]], nodes: dict[str, dict[str, Any]], elapsed_secs: float
) -> str:
    """The end-of-run table: one row per edge (see :func:`edge_rows`), then one per node."""
    rows = edge_rows(stats)
    elapsed = max(elapsed_secs, 1e-9)
    width = max([40, *(len(name) for name in rows)])
    lines = [
        f"{'topic -> node.port':{width}} {'messages':>9} {'rate_hz':>9} {'delivered':>9} "
        f"{'dropped':>8} {'unreceived':>10} {'superseded':>10} {'bad':>5} {'nonfinite':>9}"
    ]
    for name in sorted(rows):
        r = rows[name]
        lines.append(
            f"{name:{width}} {r['messages']:9d} {r['messages'] / elapsed:9.1f} "
            f"{r['delivered']:9d} {r['dropped']:8d} {r['unreceived']:10d} "
            f"{r['superseded']:10d} {r['bad_frames']:5d} {r['nonfinite']:9d}"
        )
    lines.append("")
    lines.append(f"{'node':28} {'restarts':>8} {'cpu_secs':>9} {'exit':>5}")
    for name in sorted(nodes):
        n = nodes[name]
        lines.append(f"{name:28} {n['restarts']:8d} {n['cpu_secs']:9.2f} {str(n['exit']):>5}")
    return "\n".join(lines)
