"""``bench.transport``'s rows across hosts: tcp between two network namespaces on this
machine, without and with CURVE, measured side by side in one run.

The ``raw_parts`` pair of processes (``bench.transport_bare.run_bare``) with the source in one
namespace (``10.77.0.1``) and the sink in another, at most ``NETNS_REPEATS`` repeats
alternating plain and CURVE, latency paced at ``NETNS_RATE_HZ`` (a camera's rate order,
and below what CURVE sustains for these frames). ``throughput_vs_plain`` and ``latency_vs_plain`` are the
medians over repeats of each CURVE run against the plain run next to it: what
encryption and authentication cost. Without root or ``ip`` the two rows say why they
were skipped.
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import zmq

from bench.common import Row, median, progress
from bench.netns import Net, namespaces, unavailable
from bench.transport_bare import NETNS, Measured, Sizes, figures, medians, run_bare
from runtime.security import KeyPair

NETNS_REPEATS = 3
NETNS_RATE_HZ = 100.0


def run_netns(sizes: Sizes) -> list[Row]:
    """Rows for tcp across namespaces, without and with CURVE, and what CURVE costs."""
    reason = unavailable()
    if reason is not None:
        return [{"transport": t, "impl": "raw_parts", "skipped": reason} for t in NETNS]
    repeats = min(sizes.repeats, NETNS_REPEATS)
    # CURVE moves fewer frames a second than the loopback rows' 1000 Hz: paced at
    # NETNS_RATE_HZ, the latency phase measures latency, not a queue.
    sizes = replace(
        sizes,
        rate_hz=NETNS_RATE_HZ,
        latency_frames=min(sizes.latency_frames, 300),
        throughput_frames=min(sizes.throughput_frames, 3000),
    )
    keys = tuple(KeyPair(*(k.decode() for k in zmq.curve_keypair())) for _ in range(2))
    runs: dict[str, list[Measured]] = {t: [] for t in NETNS}
    with namespaces(2) as spaces, tempfile.TemporaryDirectory(prefix="bench-netns-") as tmp:
        names = (spaces[0].name, spaces[1].name)
        points = [(r, t) for r in range(repeats) for t in (NETNS if r % 2 == 0 else NETNS[::-1])]
        label = "repeat {0[0]} {0[1]} raw_parts".format
        for repeat, transport in progress(points, "bench.transport", label=label):
            net = Net(names, (keys[0], keys[1]) if transport == "netns_curve" else None)
            workdir = Path(tmp) / f"{transport}-{repeat}"
            runs[transport].append(run_bare("raw_parts", transport, sizes, workdir, net))
    plain = runs["netns_tcp"]
    rows = []
    for transport in NETNS:
        mine = runs[transport]
        rows.append(
            {
                "transport": transport,
                "impl": "raw_parts",
                **figures(medians(mine), sizes, repeats),
                # What CURVE costs: each repeat against the plain run next to it.
                "throughput_vs_plain": median(
                    [c.frames_per_sec / p.frames_per_sec for c, p in zip(mine, plain, strict=True)]
                ),
                "latency_vs_plain": median(
                    [
                        c.latency_ms_median / p.latency_ms_median
                        for c, p in zip(mine, plain, strict=True)
                    ]
                ),
            }
        )
    return rows
