"""Introspection's cost: a graph's throughput with ``topic echo`` clients attached and without.

The graph is ``bench.transport``'s runtime pair (``bench.image_source`` ->
``bench.image_sink``, one 172 x 224 ToF frame per message over ipc, the real launcher).
Its latency phase runs at ``rate_hz`` long enough for the clients to attach; its
throughput phase (``window`` frames in flight) is what is compared. Three set-ups, side by
side in each repeat:

``alone``        no client;
``echo``         three ``python launch.py topic echo source/image --run PID --wait`` processes,
                 started before the graph (they wait for its ``status.json``), attached
                 through the throughput phase: each prints a fresh frame (arrays summarized, as
                 ``bag echo``) ten times a second, the default;
``echo_every``   the same with ``--every``: each client takes every frame it can.

Each client writes to a file; ``echoed_frames_min`` is the fewest frames one printed.
The set-ups alternate their order per repeat, so the machine's load drifts across all;
``throughput_vs_alone`` is the median over repeats of the rate divided by the ``alone``
rate measured next to it.

    python -m bench.introspection [--quick] [--json]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.common import Row, main, median, progress
from bench.transport import Measured, Sizes, run_runtime

ROOT = Path(__file__).resolve().parents[1]
SETUPS = {"alone": (0, []), "echo": (3, []), "echo_every": (3, ["--every"])}
QUICK = Sizes(latency_frames=400, throughput_frames=1000, repeats=1, rate_hz=100.0)
FULL = Sizes(latency_frames=500, throughput_frames=4000, repeats=5, rate_hz=100.0)


class Clients:
    """``count`` echo clients started once this process's graph is running."""

    def __init__(self, count: int, flags: list[str], workdir: Path) -> None:
        self.count = count
        self.flags = flags
        self.workdir = workdir
        self.procs: list[subprocess.Popen[bytes]] = []

    def __enter__(self) -> Clients:
        """Start the clients: each waits for this process's graph, then attaches."""
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        for i in range(self.count):
            with (self.workdir / f"echo{i}.txt").open("wb") as out:
                cmd = [sys.executable, str(ROOT / "launch.py"), "topic", "echo", "source/image"]
                cmd += ["--run", str(os.getpid()), "--wait", "120", "--timeout", "3", *self.flags]
                self.procs.append(subprocess.Popen(cmd, stdout=out, env=env, cwd=ROOT))
        return self

    def __exit__(self, *exc: object) -> None:
        for proc in self.procs:
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def echoed(self) -> int:
        """The fewest frames one client printed (0 without clients)."""
        counts = [
            sum(1 for line in path.open() if line.startswith("--- source/image #"))
            for path in sorted(self.workdir.glob("echo*.txt"))
        ]
        return min(counts) if len(counts) == self.count and counts else 0


def run(quick: bool) -> list[Row]:
    """Each repeat: every set-up, alternating the order."""
    sizes = QUICK if quick else FULL
    names = list(SETUPS)
    measured: dict[str, list[Measured]] = {n: [] for n in names}
    echoed: dict[str, list[int]] = {n: [] for n in names}
    with tempfile.TemporaryDirectory(prefix="bench-introspection-") as tmp:
        points = [
            (repeat, name)
            for repeat in range(sizes.repeats)
            for name in (names if repeat % 2 == 0 else names[::-1])
        ]
        label = "repeat {0[0]}, {0[1]}".format
        for repeat, name in progress(points, "bench.introspection", label=label):
            workdir = Path(tmp) / f"{repeat}-{name}"
            workdir.mkdir()
            count, flags = SETUPS[name]
            with Clients(count, flags, workdir) as clients:
                measured[name].append(run_runtime("ipc", sizes, workdir))
            echoed[name].append(clients.echoed())
    alone = measured["alone"]
    rows = []
    for name in names:
        paired = [
            m.frames_per_sec / a.frames_per_sec for m, a in zip(measured[name], alone, strict=True)
        ]
        rows.append(
            {
                "setup": name,
                "echo_clients": SETUPS[name][0],
                "frames_per_sec": median([m.frames_per_sec for m in measured[name]]),
                "throughput_vs_alone": median(paired),
                "throughput_vs_alone_min": min(paired),
                "latency_ms_median": median([m.latency_ms_median for m in measured[name]]),
                "echoed_frames_min": min(echoed[name]),
                "drops": sum(m.drops for m in measured[name]),
                "repeats": sizes.repeats,
                "throughput_frames": sizes.throughput_frames,
            }
        )
    return rows


if __name__ == "__main__":
    main(
        "introspection",
        run,
        columns=[
            "setup",
            "echo_clients",
            "frames_per_sec",
            "throughput_vs_alone",
            "throughput_vs_alone_min",
            "latency_ms_median",
            "echoed_frames_min",
            "drops",
            "repeats",
        ],
    )
