"""Stamp order across a node's inputs: a decision from several inputs made alike live and
in a replay.

A node that decides from several inputs (a supervisor that releases on the shear and
squeezes on a slip) receives their messages in an order set by their paths: a slip
onset goes camera -> wrench -> slip -> supervisor, the shear of the same frame camera ->
shear -> supervisor, and which one arrives first is timing. A recording keeps the
order its recorder saw, and a replay hands the bag's order over: live and replayed, the
node could decide differently on the same messages.

A node names such inputs in ``Node.ordered_inputs``; the runtime (``runtime.runner``,
and ``runtime.testing`` when asked) then holds each message of those inputs until
every other of them has advanced past its stamp (its newest message is stamped later,
or the same and the input comes later in the node's declaration), and hands them over
by (stamp, input in declaration order, arrival). That order depends on the messages
alone, not on how they interleaved on their way, as long as each input's stamps do not
go back. Live, a message is held at most ``Node.order_window_secs`` of the wall clock
(an input that is silent, or a path that lags more, must not stall the node): the
bound on the latency this adds, and on how far apart two paths may be for the order to
be exact. In lockstep there is no such bound: what is still held when the bag ends is
handed over, in the same order, once the replay has sent its last message.

Live, a node may also say which of the others each input's messages wait for
(``Node.order_waits``): a release decided on the shear need not wait for the slip path,
the longest, when the shear rule reads nothing the slip brings. Such a message is handed
over once the inputs it waits for have advanced past its stamp and none of their held
messages sorts before it; a message of an input it does not wait for may then come after
it although stamped earlier. Two inputs that wait for each other keep their exact order;
in lockstep every input waits for every other (the order is the total one above).
"""

from __future__ import annotations

import bisect
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any


def stamp_of(msg: Any) -> int:
    """A message's ``header.stamp_nanos`` (0 for one without a header)."""
    header = getattr(msg, "header", None)
    return int(header.stamp_nanos) if header is not None else 0


class StampOrder:
    """Holds messages of ``ports`` until no earlier-stamped one can come on another.

    ``window_nanos``: live, the longest a message is held (None: no bound, lockstep).
    ``waits``: live, per input, the other inputs its messages wait for (an input not
    named waits for every other; inputs not in ``ports`` are left out); ignored in
    lockstep, where each waits for every other.
    """

    def __init__(
        self,
        ports: Sequence[str],
        window_nanos: int | None,
        waits: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        self.rank = {port: k for k, port in enumerate(ports)}
        self.window_nanos = window_nanos
        live = waits if window_nanos is not None else None
        everyone = frozenset(self.rank)
        self.waits = {
            port: (frozenset(live[port]) if live and port in live else everyone) & everyone - {port}
            for port in self.rank
        }
        self.newest: dict[str, int] = {}  # per input: the newest stamp received
        # (stamp, rank, arrival, port, message, deadline), kept sorted.
        self._held: list[tuple[int, int, int, str, Any, int]] = []
        self._arrivals = 0

    def __contains__(self, port: str) -> bool:
        return port in self.rank

    def add(self, port: str, msg: Any, now_nanos: int = 0) -> None:
        """Hold ``msg`` of input ``port`` (one of ``ports``), received at ``now_nanos``."""
        stamp = stamp_of(msg)
        self.newest[port] = max(stamp, self.newest.get(port, stamp))
        deadline = now_nanos + (self.window_nanos or 0)
        bisect.insort(self._held, (stamp, self.rank[port], self._arrivals, port, msg, deadline))
        self._arrivals += 1

    def _settled(self, stamp: int, rank: int, port: str) -> bool:
        """Whether no input ``port``'s messages wait for can still bring a message that
        sorts before ``(stamp, rank)``."""
        for other_port in self.waits[port]:
            other = self.rank[other_port]
            newest = self.newest.get(other_port)
            if newest is None or newest < stamp or (newest == stamp and other < rank):
                return False
        return True

    def ready(self, now_nanos: int | None = None) -> list[tuple[str, Any]]:
        """Take the messages that may be handled now, in order: those settled, and, given
        ``now_nanos`` and a window, those held past it (with every one before them)."""
        out: list[tuple[str, Any]] = []
        held = self._held
        while held and now_nanos is not None and (due := self.due_nanos()) is not None:
            if due > now_nanos:
                break
            out.append((held[0][3], held.pop(0)[4]))
        kept: list[tuple[int, int, int, str, Any, int]] = []
        waiting: set[str] = set()  # inputs with a message still held, earlier in the order
        for item in held:
            stamp, rank, _, port, msg, _ = item
            if (
                port in waiting
                or waiting & self.waits[port]
                or not self._settled(stamp, rank, port)
            ):
                waiting.add(port)
                kept.append(item)
            else:
                out.append((port, msg))
        self._held = kept
        return out

    def flush(self) -> list[tuple[str, Any]]:
        """Take every held message, in order (lockstep, once nothing more can come)."""
        out = [(item[3], item[4]) for item in sorted(self._held)]
        self._held.clear()
        return out

    def due_nanos(self) -> int | None:
        """When the oldest held message's window ends (live); None when none is held."""
        if not self._held or self.window_nanos is None:
            return None
        return min(item[5] for item in self._held)

    def pending(self) -> dict[str, int]:
        """How many messages each input has held."""
        return dict(Counter(item[3] for item in self._held))
