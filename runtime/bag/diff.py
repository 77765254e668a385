"""Compare two bags message by message: what ``launch.py bag diff`` prints.

Messages of a topic are paired by their stamp (``header.stamp_nanos``, MCAP
``publish_time``): a node stamps an answer with the stamp of the message it answers
(a pose with its contact patch's), so the answers to one input pair up whatever else
one side lost or added. Messages with the same stamp pair in their order; a type
without a header (stamp 0) pairs by position. Per topic the differences come in this
order: one ``(count)`` line when the counts differ, the fields of each pair that
differ, then the messages only one side has (``(only in A)``, ``(only in B)``).

Fields a message type declares as wall-clock measurements
(``Message.wall_clock_fields``, a solve time) are not compared: two runs of the same
input differ there by nature; nor is ``header.seq``, the message's position in its
topic, which the pairing accounts for. Numbers and arrays compare with ``numpy.isclose``
tolerances (NaN equals NaN). Values are decoded from each bag's stored description, so
bags recorded before a type changed still compare.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import messages  # noqa: F401  (declares the types whose wall-clock fields are skipped)
from messages.base import Message
from messages.errors import BagError
from runtime.bag.message import BagMessage
from runtime.bag.reader import BagReader

COUNT, ONLY_A, ONLY_B = "(count)", "(only in A)", "(only in B)"
# A message's position in its topic, not its content: after one missing message every
# later one would differ there. The pairing reports what is missing instead.
POSITION = frozenset({"header.seq"})


@dataclass
class Difference:
    """One difference: ``index`` is the message's position in its topic in A (in B for
    one only B has; -1 for a count) and ``stamp`` the stamp it was paired by."""

    topic: str
    index: int
    field: str
    detail: str
    stamp: int | None = None

    def __str__(self) -> str:
        if self.index < 0:
            return f"{self.topic} {self.field}: {self.detail}"
        at = f" stamp {self.stamp}" if self.stamp else ""
        return f"{self.topic} #{self.index}{at} {self.field}: {self.detail}"


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


def wall_clock_fields(type_name: str) -> frozenset[str]:
    """The fields today's declaration of ``type_name`` marks as wall-clock measurements."""
    cls = Message.registry.get(type_name)
    return frozenset(cls.wall_clock_fields) if cls is not None else frozenset()


def pair_by_stamp(
    msgs_a: Sequence[BagMessage], msgs_b: Sequence[BagMessage]
) -> tuple[list[tuple[int, int]], list[int], list[int]]:
    """``(pairs of indices, indices only in A, indices only in B)``: the k-th message of a
    stamp in A pairs with the k-th of that stamp in B."""
    by_key: dict[tuple[int, int], int] = {}
    seen: dict[int, int] = defaultdict(int)
    for index, msg in enumerate(msgs_b):
        stamp = msg.publish_time_nanos
        by_key[(stamp, seen[stamp])] = index
        seen[stamp] += 1
    seen.clear()
    pairs: list[tuple[int, int]] = []
    only_a: list[int] = []
    for i, msg in enumerate(msgs_a):
        stamp = msg.publish_time_nanos
        match = by_key.pop((stamp, seen[stamp]), None)
        seen[stamp] += 1
        if match is None:
            only_a.append(i)
        else:
            pairs.append((i, match))
    return pairs, only_a, sorted(by_key.values())


def diff_topic(
    topic: str,
    msgs_a: Sequence[BagMessage],
    msgs_b: Sequence[BagMessage],
    *,
    rtol: float,
    atol: float,
    ignore: frozenset[str],
    strict: bool,
) -> list[Difference]:
    """The differences of one topic (see the module docstring for their order)."""
    out: list[Difference] = []
    if len(msgs_a) != len(msgs_b):
        out.append(Difference(topic, -1, COUNT, f"{len(msgs_a)} vs {len(msgs_b)} messages"))
    pairs, only_a, only_b = pair_by_stamp(msgs_a, msgs_b)
    for i, j in pairs:
        ma, mb = msgs_a[i], msgs_b[j]
        stamp = ma.publish_time_nanos
        ta, tb = ma.channel.schema.type_name, mb.channel.schema.type_name
        if ta != tb:
            out.append(Difference(topic, i, "(type)", f"{ta} vs {tb}", stamp))
            continue
        try:
            plain_a = ma.decode_plain()
            plain_b = mb.decode_plain()
        except BagError as err:
            if strict:
                raise
            out.append(Difference(topic, i, "(undecodable)", str(err), stamp))
            continue
        skip = ignore | POSITION | wall_clock_fields(ta)
        found = compare_values(plain_a, plain_b, rtol=rtol, atol=atol, ignore=skip)
        out += [Difference(topic, i, name, detail, stamp) for name, detail in found]
    for side, msgs, indices in ((ONLY_A, msgs_a, only_a), (ONLY_B, msgs_b, only_b)):
        for k in indices:
            msg = msgs[k]
            detail = f"{msg.channel.schema.type_name} seq {msg.sequence}"
            out.append(Difference(topic, k, side, detail, msg.publish_time_nanos))
    return out


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
    """Per-message differences of ``topics`` (default: every topic of either bag).

    A paired message that cannot be decoded on either side is one ``(undecodable)``
    difference and the comparison goes on; with ``strict`` its :class:`BagError` ends
    the diff.
    """
    with BagReader(path_a) as ra, BagReader(path_b) as rb:
        if topics:
            ra.require_topics(topics)
            rb.require_topics(topics)
            chosen = list(topics)
        else:
            chosen = sorted(set(ra.topics()) | set(rb.topics()))
        out: list[Difference] = []
        for topic in chosen:
            out += diff_topic(
                topic,
                list(ra.messages([topic])),
                list(rb.messages([topic])),
                rtol=rtol,
                atol=atol,
                ignore=frozenset(ignore),
                strict=strict,
            )
        return out


def summary(diffs: Sequence[Difference]) -> str:
    """The last line ``bag diff`` prints."""
    if not diffs:
        return "no differences"
    missing = [d for d in diffs if d.field in (ONLY_A, ONLY_B)]
    fields = [d for d in diffs if d.field not in (COUNT, ONLY_A, ONLY_B)]
    parts = []
    if fields:
        paired = len({(d.topic, d.index) for d in fields})
        parts.append(f"{len(fields)} difference(s) in {paired} message(s)")
    for side, name in ((ONLY_A, "A"), (ONLY_B, "B")):
        n = sum(d.field == side for d in missing)
        if n:
            parts.append(f"{n} message(s) only in {name}")
    return "; ".join(parts) or f"{len(diffs)} difference(s)"
