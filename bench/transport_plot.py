"""The plot of ``python -m bench.transport``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.common import Row


def plot(rows: list[Row], path: Path) -> None:
    """Throughput, latency and CPU per frame, as bars per transport and implementation
    (those measured with every implementation: not the namespace rows)."""
    import matplotlib.pyplot as plt

    impls = list(dict.fromkeys(r["impl"] for r in rows))
    transports = [
        t
        for t in dict.fromkeys(r["transport"] for r in rows)
        if {r["impl"] for r in rows if r["transport"] == t} == set(impls)
    ]

    fig, (ax_rate, ax_lat, ax_cpu) = plt.subplots(1, 3, figsize=(14, 4))
    width = 0.8 / len(impls)
    x = np.arange(len(transports))
    for i, impl in enumerate(impls):
        mine = [
            next(r for r in rows if r["transport"] == t and r["impl"] == impl) for t in transports
        ]
        at = x + (i - (len(impls) - 1) / 2) * width
        color = f"C{i}"
        ax_rate.bar(at, [r["frames_per_sec"] for r in mine], width, color=color, label=impl)
        medians = [r["latency_ms_median"] for r in mine]
        p99s = [r["latency_ms_p99"] for r in mine]
        ax_lat.bar(at, medians, width, color=color, label=f"{impl} median")
        ax_lat.scatter(at, p99s, color=color, marker="_", s=200, label=f"{impl} p99")
        source = [r["source_cpu_us_per_frame"] for r in mine]
        ax_cpu.bar(at, source, width, color=color, label=f"{impl} source")
        ax_cpu.bar(
            at,
            [r["sink_cpu_us_per_frame"] for r in mine],
            width,
            bottom=source,
            color=color,
            alpha=0.5,
            label=f"{impl} sink",
        )
    for ax in (ax_rate, ax_lat, ax_cpu):
        ax.set_xticks(x, transports)
        ax.legend(fontsize=7)
    ax_rate.set_ylabel("frames / s (172x224 depth f32 + IR u16)")
    ax_rate.set_title(f"throughput, {rows[0]['window']} frames in flight")
    ax_lat.set_yscale("log")
    ax_lat.set_ylabel("latency, ms (bar: median, tick: p99)")
    ax_lat.set_title(f"latency at {rows[0]['rate_hz']:g} Hz")
    ax_cpu.set_ylabel("process CPU, us per frame")
    ax_cpu.set_title("CPU per frame (solid: source, light: sink)")
    fig.suptitle(f"bench.transport: medians of {rows[0]['repeats']} repeats")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
