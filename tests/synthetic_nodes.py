"""Synthetic nodes for the tests: a counter source, a relay, a fan-in merge and a sink.

They exercise the runtime without any sensor. They are not production nodes: they are
registered (``synthetic.*``) when this module is imported, which ``tests/conftest.py``
does for every test process. A launcher started in a subprocess registers only the
production nodes, so graphs it runs name these as ``module:Class``
(:data:`IMPLS`; ``tests/runtime/conftest.py`` writes them so).

Ports (all :class:`messages.Tick`):
    synthetic.source   outputs: tick         (``count`` ticks at ``rate_hz``, then asks to stop)
    synthetic.relay    inputs: tick          outputs: tick  (adds ``add``; optional work and crash)
    synthetic.merge    inputs: a, b          outputs: tick  (fan-in: forwards both, in arrival order)
    synthetic.sink     inputs: tick, other   (writes what it got to ``out_path`` as JSON lines)
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from bench.hosts import TickMerge
from messages import Header, Tick
from runtime.node import Node
from runtime.registry import class_path, register


class SourceParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rate_hz: Annotated[float, Meta(gt=0, description="ticks per second")] = 20.0
    count: Annotated[int, Meta(ge=0, description="ticks to send")] = 100
    payload_bytes: Annotated[int, Meta(ge=0, description="zero bytes carried by each tick")] = 0
    stop_when_done: bool = True


@register("synthetic.source")
class SyntheticSource(Node):
    """Publishes ``count`` ticks (value = index) at ``rate_hz``."""

    Params = SourceParams
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.sent = 0
        self.payload = np.zeros(self.params.payload_bytes, np.uint8)
        self.io.add_timer(1.0 / self.params.rate_hz, self.tick)

    def tick(self) -> None:
        if self.sent >= self.params.count:
            return
        msg = Tick(
            header=Header(stamp_nanos=self.io.now_nanos()),
            value=float(self.sent),
            payload=self.payload,
        )
        self.io.publish("tick", msg)
        self.sent += 1
        if self.sent == self.params.count and self.params.stop_when_done:
            self.io.request_stop(f"sent {self.sent} ticks")


class RelayParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    add: float = 0.0
    work_secs: Annotated[float, Meta(ge=0)] = 0.0
    crash_after: Annotated[int, Meta(ge=0)] = 0
    crash_marker: str = ""


@register("synthetic.relay")
class SyntheticRelay(Node):
    """Forwards each tick with ``add`` added, after ``work_secs`` of busy work.

    With ``crash_after`` > 0 it dies (exit code 3) after that many messages, once: it
    leaves ``crash_marker`` behind so its restarted incarnation runs normally.
    """

    Params = RelayParams
    inputs = {"tick": Tick}
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.seen = 0

    def on_tick(self, msg: Tick) -> None:
        if self.params.work_secs:
            end = time.perf_counter() + self.params.work_secs
            while time.perf_counter() < end:
                pass
        self.seen += 1
        marker = Path(self.params.crash_marker) if self.params.crash_marker else None
        if self.params.crash_after and self.seen >= self.params.crash_after:
            if marker is None or not marker.exists():
                if marker is not None:
                    marker.touch()
                os._exit(3)
        out = Tick(
            header=Header(stamp_nanos=msg.header.stamp_nanos),
            value=msg.value + self.params.add,
            payload=msg.payload,
        )
        self.io.publish("tick", out)


# The fan-in is bench.hosts's (a bench cannot import the tests; the tests can it).
SyntheticMerge = register("synthetic.merge")(TickMerge)


class SinkParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    out_path: str = ""
    work_secs: Annotated[float, Meta(ge=0)] = 0.0


@register("synthetic.sink")
class SyntheticSink(Node):
    """Collects ticks; on stop, logs a summary and writes them to ``out_path`` (JSON lines)."""

    Params = SinkParams
    inputs = {"tick": Tick, "other": Tick}
    optional_inputs = frozenset({"other"})

    def setup(self) -> None:
        self.rows: list[dict[str, float | int | str]] = []

    def _take(self, port: str, msg: Tick) -> None:
        if self.params.work_secs:
            time.sleep(self.params.work_secs)
        latency = (time.time_ns() - msg.header.stamp_nanos) / 1e6
        self.rows.append(
            {
                "port": port,
                "seq": msg.header.seq,
                "stamp_nanos": msg.header.stamp_nanos,
                "value": msg.value,
                "latency_ms": latency,
            }
        )

    def on_tick(self, msg: Tick) -> None:
        self._take("tick", msg)

    def on_other(self, msg: Tick) -> None:
        self._take("other", msg)

    def teardown(self) -> None:
        if self.rows:
            latencies = sorted(r["latency_ms"] for r in self.rows)
            self.io.log.info(
                "received %d ticks, median latency %.3f ms",
                len(self.rows),
                latencies[len(latencies) // 2],
            )
        else:
            self.io.log.info("received no ticks")
        if self.params.out_path:
            with open(self.params.out_path, "w") as f:
                for row in self.rows:
                    f.write(json.dumps(row) + "\n")


IMPLS = {
    name: class_path(cls)
    for name, cls in (
        ("synthetic.source", SyntheticSource),
        ("synthetic.relay", SyntheticRelay),
        ("synthetic.merge", SyntheticMerge),
        ("synthetic.sink", SyntheticSink),
    )
}
"""Each synthetic node's registered name and its ``module:Class``, which any process
can import."""
