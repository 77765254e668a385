"""The launcher's end-of-run table, from the counters the nodes report.

Per topic: messages published, the rate, and what its subscribers lost (``dropped``),
skipped on purpose (``superseded``), could not decode (``bad``) and received with a
NaN or infinity where the type says a number is finite (``nonfinite``). Per node:
restarts, CPU seconds, the last exit code.

``dropped`` is what the receivers counted from sequence gaps, but never more than what
the publisher sent and the receiver did not take off its socket: a corrupted
``header.seq`` cannot make a topic lose more messages than it carried, and a frame that
arrived but did not decode is ``bad``, not also dropped.
"""

from __future__ import annotations

from typing import Any

from runtime.protocol import INPUT_COUNTERS

_COLUMNS = ("dropped", "superseded", "bad_frames", "nonfinite")


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


def topic_totals(stats: dict[str, dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per topic: messages published and the summed counters of its subscribers."""
    topics: dict[str, dict[str, int]] = {}

    def row(topic: str) -> dict[str, int]:
        return topics.setdefault(topic, dict.fromkeys(("messages", *_COLUMNS), 0))

    for node_stats in stats.values():
        for topic, count in node_stats.get("published", {}).items():
            row(topic)["messages"] += count
    published = {topic: r["messages"] for topic, r in topics.items()}
    for node_stats in stats.values():
        for inp in node_stats.get("inputs", {}).values():
            r = row(inp["topic"])
            dropped = inp["dropped"]
            if inp["topic"] in published:
                dropped = min(dropped, max(0, published[inp["topic"]] - inp["received"]))
            r["dropped"] += dropped
            for key in _COLUMNS[1:]:
                r[key] += inp.get(key, 0)
    return topics


def table(
    stats: dict[str, dict[str, Any]], nodes: dict[str, dict[str, Any]], elapsed_secs: float
) -> str:
    """The end-of-run table: one row per topic, then one per node."""
    topics = topic_totals(stats)
    elapsed = max(elapsed_secs, 1e-9)
    lines = [
        f"{'topic':40} {'messages':>9} {'rate_hz':>9} {'dropped':>8} {'superseded':>10} "
        f"{'bad':>5} {'nonfinite':>9}"
    ]
    for topic in sorted(topics):
        r = topics[topic]
        lines.append(
            f"{topic:40} {r['messages']:9d} {r['messages'] / elapsed:9.1f} {r['dropped']:8d} "
            f"{r['superseded']:10d} {r['bad_frames']:5d} {r['nonfinite']:9d}"
        )
    lines.append("")
    lines.append(f"{'node':28} {'restarts':>8} {'cpu_secs':>9} {'exit':>5}")
    for name in sorted(nodes):
        n = nodes[name]
        lines.append(f"{name:28} {n['restarts']:8d} {n['cpu_secs']:9.2f} {str(n['exit']):>5}")
    return "\n".join(lines)
