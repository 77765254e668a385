"""Transport: the runtime's node processes against raw pyzmq, over ipc and tcp.

One frame is one :class:`messages.ToFImage` of one sensor: a 172 x 224 depth image
(float32) and IR image (uint16), 231,168 bytes of pixels, sent between two processes.
Three implementations run side by side, in the same run, alternating per repeat:

``runtime``  the real path: a graph of ``bench.image_source`` -> ``bench.image_sink``
             (``bench/nodes.py``) started by :class:`runtime.launcher.Launcher`;
             each node is a ``runtime.runner`` child (XPUB publisher, SUB input, poll
             loop, timers, the codec). tcp places both nodes on ``host: 127.0.0.1``.
``codec``    two bare processes with pyzmq PUB/SUB that encode and decode with
             ``messages.codec`` (no node runner): splits the runtime's cost between
             codec and the runner loop.
``raw``      two bare processes with pyzmq PUB/SUB sending the same pixel buffers as
             ``[topic, 16-byte stamp/seq + frame id, depth, ir]`` with pyzmq's
             ``send_multipart``/``recv_multipart``, ``copy=False``: the target's baseline.
``raw_parts`` ``raw`` with the runtime's own part loops (``runtime.zmqio.send_parts``,
             ``recv_parts``) instead of pyzmq's multipart helpers: what the runtime's
             way of driving pyzmq is worth on its own, so a ratio against ``raw`` is
             not read as the runtime using a cheaper socket.

Every implementation runs the same protocol (:class:`bench.nodes.WindowPlan` and
:class:`bench.nodes.SinkRecord`): a latency phase at ``rate_hz`` (stamp with
``time.time_ns`` just before encoding, latency measured once the receiver holds the
decoded frame), then a throughput phase with at most ``window`` frames in flight,
acknowledged every ``ack_every`` frames over a return channel (a Tick edge for the
runtime, PUSH/PULL for the bare processes). Throughput is counted at the receiver:
``(frames - 1) / (last - first receive time)``. Frames lost at a high-water mark
(sequence gaps) are counted as ``drops``.

Two more rows, ``netns_tcp`` and ``netns_curve``: the ``raw_parts`` pair between two
network namespaces (two hosts on one machine), plain and CURVE-encrypted, and the ratio
CURVE costs (``bench.transport_netns``; skipped, with the reason, without root).

Rows report medians over repeats (of each repeat's rate, median and p99 latency).
``throughput_vs_raw`` is the median over repeats of the rate divided by raw's rate in
the same repeat and transport (measured minutes apart, the machine's load drifts more
than it does within one repeat), ``throughput_vs_raw_min``/``_max`` their range. Within
a repeat ``runtime`` and ``raw`` run one right after the other, in alternating order,
and a full run has 9 short repeats rather than a few long ones: the median of many
adjacent pairs is what a loaded machine disturbs least;
``latency_vs_raw`` divides by the raw row's median latency; ``source_cpu_vs_raw`` and
``sink_cpu_vs_raw`` are the CPU per frame of each side against raw's, paired by repeat
as the throughput is (``_min``/``_max`` their range).

Where the runtime's extra CPU per frame goes, step by step (message, encode, finite
check, send; receive, decode, delivery), side by side with the raw pair's in one
process: ``python -m bench.transport_steps``.

    python -m bench.transport [--quick] [--json] [--no-plot]
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from bench.common import Row, launcher_log, main, median, progress
from bench.transport_bare import (
    COLS,
    FULL,
    QUICK,
    ROWS,
    Measured,
    Sizes,
    _summarise,
    figures,
    medians,
    run_bare,
)
from bench.transport_netns import run_netns
from runtime.graph import check
from runtime.launcher import Launcher

TRANSPORTS = ("ipc", "tcp")
# runtime and raw next to each other in either order (a repeat runs this order or its
# reverse): each repeat's ratio compares two runs seconds apart.
IMPLS = ("runtime", "raw", "codec", "raw_parts")


# -- the runtime: a two-node graph under the real launcher -------------------------


def run_runtime(transport: str, sizes: Sizes, workdir: Path) -> Measured:
    """Launch ``bench.image_source -> bench.image_sink`` and read what the sink measured."""
    out_path = workdir / "sink.json"
    source_path = workdir / "source.json"
    host = {"host": "127.0.0.1"} if transport == "tcp" else {}
    doc = {
        "nodes": {
            "source": {
                "impl": "bench.image_source",
                "params": {
                    "rows": ROWS,
                    "cols": COLS,
                    "latency_frames": sizes.latency_frames,
                    "rate_hz": sizes.rate_hz,
                    "throughput_frames": sizes.throughput_frames,
                    "window": sizes.window,
                    "out_path": str(source_path),
                },
                "inputs": {"ack": "sink/ack"},
                **host,
            },
            "sink": {
                "impl": "bench.image_sink",
                "params": {"out_path": str(out_path), "ack_every": sizes.ack_every},
                "inputs": {"image": {"from": "source/image", "queue_size": sizes.hwm}},
                **host,
            },
        }
    }
    with launcher_log("transport") as log:
        code = Launcher(check(doc, source="bench.transport"), out=log).run()
    if code != 0 or not out_path.exists() or not source_path.exists():
        raise RuntimeError(
            f"the runtime graph failed (exit {code}); see bench/results/transport.log"
        )
    return _summarise(json.loads(out_path.read_text()), json.loads(source_path.read_text()))


# -- the sweep -------------------------------------------------------------------------


def measure(impl: str, transport: str, sizes: Sizes, workdir: Path) -> Measured:
    """One repeat of one implementation over one transport."""
    if impl == "runtime":
        return run_runtime(transport, sizes, workdir)
    return run_bare(impl, transport, sizes, workdir)


def run(quick: bool, sizes: Sizes | None = None) -> list[Row]:
    """Every transport and implementation, ``repeats`` times, as table rows of medians."""
    sizes = sizes or (QUICK if quick else FULL)
    runs: dict[tuple[str, str], list[Measured]] = {}
    with tempfile.TemporaryDirectory(prefix="bench-transport-") as tmp:
        # Alternate the order so a drift of the machine's load hits every impl.
        points = [
            (repeat, transport, impl)
            for repeat in range(sizes.repeats)
            for transport in TRANSPORTS
            for impl in (IMPLS if repeat % 2 == 0 else IMPLS[::-1])
        ]
        label = "repeat {0[0]} {0[1]} {0[2]}".format
        for repeat, transport, impl in progress(points, "bench.transport", label=label):
            workdir = Path(tmp) / f"{impl}-{transport}-{repeat}"
            workdir.mkdir()
            runs.setdefault((transport, impl), []).append(measure(impl, transport, sizes, workdir))
    return _rows(runs, sizes) + run_netns(sizes)


def _rows(runs: dict[tuple[str, str], list[Measured]], sizes: Sizes) -> list[Row]:
    """One row per transport and implementation, with ratios against ``raw``."""
    rows: list[Row] = []
    for transport in TRANSPORTS:
        raw_runs = runs[(transport, "raw")]
        raw = medians(raw_runs)
        for impl in IMPLS:
            m = medians(runs[(transport, impl)])
            # Each repeat's ratio against raw measured next to it: the machine's load
            # drifts between repeats far more than it does within one.
            pairs = list(zip(runs[(transport, impl)], raw_runs, strict=True))
            paired = [mine.frames_per_sec / theirs.frames_per_sec for mine, theirs in pairs]
            rows.append(
                {
                    "transport": transport,
                    "impl": impl,
                    **figures(m, sizes, sizes.repeats),
                    "throughput_vs_raw": median(paired),
                    "throughput_vs_raw_min": min(paired),
                    "throughput_vs_raw_max": max(paired),
                    "latency_vs_raw": m.latency_ms_median / raw.latency_ms_median,
                    **_cpu_ratios(pairs),
                }
            )
    return rows


def _cpu_ratios(pairs: list[tuple[Measured, Measured]]) -> Row:
    """Each side's CPU per frame against raw's in the same repeat, as for throughput: the
    median over repeats and the range."""
    out: Row = {}
    for side in ("source", "sink"):
        key = f"{side}_cpu_us_per_frame"
        ratios = [getattr(mine, key) / getattr(raw, key) for mine, raw in pairs]
        out[f"{side}_cpu_vs_raw"] = median(ratios)
        out[f"{side}_cpu_vs_raw_min"] = min(ratios)
        out[f"{side}_cpu_vs_raw_max"] = max(ratios)
    return out


COLUMNS = [
    "transport",
    "impl",
    "frames_per_sec",
    "throughput_vs_raw",
    "latency_ms_median",
    "latency_ms_p99",
    "latency_vs_raw",
    "source_cpu_us_per_frame",
    "source_cpu_vs_raw",
    "sink_cpu_us_per_frame",
    "sink_cpu_vs_raw",
    # The node's own loop (each side's main thread): where the runtime's Python shows.
    "source_main_us_per_frame",
    "sink_main_us_per_frame",
    "drops",
    "repeats",
    "throughput_vs_plain",
    "latency_vs_plain",
    "skipped",
]

if __name__ == "__main__":
    from bench.transport_plot import plot

    main("transport", run, columns=COLUMNS, plot=plot)
