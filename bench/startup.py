"""How long the command line takes to start and to stop (medians of 5 runs).

python -m bench.startup [--json] [--quick]

Rows, each timed from a fresh ``python launch.py`` process:

- ``--help`` and ``bag info`` (a small bag written here): no node module is imported;
- ``--check graph.yaml``: only the modules of the graph's nodes;
- ``graph.yaml ready``: from the launch to the launcher's "all nodes ready" line, nodes
  forked from the launcher's fork server (``runtime.child``); and, interleaved with it,
  the same with ``SBG_NODE_START=spawn`` (a fresh Python that imports each node's
  modules itself): ``vs_fork`` is the ratio of the medians;
- ``ctrl-c while running``: from SIGINT to the launcher's exit (every node stopped);
- ``ctrl-c while starting``: SIGINT as soon as the nodes are spawned, to the exit.

For the three commands ``cpu_median_s`` is their CPU time (user + system), which a loaded
machine inflates far less than the wall time.

``--quick`` (the smoke test) runs each once, with two nodes of ``graph.yaml``
(``--only world,gripper``) in place of the whole graph. The goals hold on a quiet machine; on a loaded one every figure grows.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.common import Row, main, median
from runtime.child import START_ENV

ROOT = Path(__file__).resolve().parent.parent
RUNS = 5
GRAPH = ROOT / "graph.yaml"
QUICK_ONLY = ["--only", "world,gripper"]


def _launch(*args: str, spawn: bool = False) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if spawn:
        env[START_ENV] = "spawn"
    return subprocess.Popen(
        [sys.executable, str(ROOT / "launch.py"), *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _cpu_of_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _time_command(*args: str) -> tuple[float, float]:
    """Wall and CPU seconds for ``launch.py ARGS`` to run to its end (it must succeed).

    The CPU time barely depends on how loaded the machine is; the wall time does.
    """
    cpu = _cpu_of_children()
    start = time.perf_counter()
    proc = _launch(*args)
    out, _ = proc.communicate(timeout=120)
    took = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"launch.py {' '.join(args)} exited {proc.returncode}:\n{out}")
    return took, _cpu_of_children() - cpu


def _time_graph(args: list[str], signal_on: str, spawn: bool = False) -> tuple[float, float]:
    """Launch ``launch.py ARGS``; seconds to the line containing ``signal_on``, then seconds from a
    SIGINT sent at that line to the launcher's exit (which must be 130)."""
    start = time.perf_counter()
    proc = _launch(*args, spawn=spawn)
    seen = threading.Event()
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if signal_on in line:
                seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    if not seen.wait(timeout=120):
        proc.kill()
        raise RuntimeError(f"{signal_on!r} not seen:\n{''.join(lines)}")
    ready = time.perf_counter() - start
    sent = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=60)
    stop = time.perf_counter() - sent
    reader.join(timeout=5)
    if code != 130:
        raise RuntimeError(f"exit code {code} after SIGINT, expected 130:\n{''.join(lines)}")
    return ready, stop


def _bag(folder: Path) -> Path:
    from messages import Header, Tick
    from runtime.bag import BagWriter

    path = folder / "small.mcap"
    with BagWriter(path) as writer:
        writer.add_run_info(graph_text=GRAPH.read_text(), command_line="launch.py graph.yaml")
        for i in range(100):
            msg = Tick(header=Header(stamp_nanos=i, seq=i), value=float(i))
            writer.write_message("src/tick", msg, log_time_nanos=i * 1_000_000)
    return path


def _row(what: str, seconds: list[float], goal_s: float, cpu: list[float] | None = None) -> Row:
    med = median(seconds)
    return {
        "what": what,
        "median_s": med,
        "min_s": min(seconds),
        "max_s": max(seconds),
        "cpu_median_s": median(cpu) if cpu else float("nan"),
        "runs": len(seconds),
        "goal_s": goal_s,
        "meets_goal": "yes" if med < goal_s else "no",
        "vs_fork": float("nan"),
    }


def _command_row(what: str, args: list[str], runs: int, goal_s: float) -> Row:
    timed = [_time_command(*args) for _ in range(runs)]
    return _row(what, [wall for wall, _ in timed], goal_s, [cpu for _, cpu in timed])


def run(quick: bool) -> list[Row]:
    runs = 1 if quick else RUNS
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bag = _bag(folder)
        graph = [GRAPH.name, *(QUICK_ONLY if quick else [])]
        name = " ".join(graph)
        rows = [
            _command_row("--help", ["--help"], runs, 0.5),
            _command_row("bag info", ["bag", "info", str(bag)], runs, 0.5),
            _command_row(f"--check {name}", [*graph, "--check"], runs, 1.0),
        ]
        running, spawned = [], []
        for _ in range(runs):  # side by side: forked nodes, then fresh Pythons
            running.append(_time_graph(graph, "all nodes ready"))
            spawned.append(_time_graph(graph, "all nodes ready", spawn=True))
        starting = [_time_graph(graph, "starting ") for _ in range(runs)]
    rows.append(_row(f"{name} ready", [r for r, _ in running], 3.0))
    rows.append(_row(f"{name} ready, {START_ENV}=spawn", [r for r, _ in spawned], 3.0))
    rows[-1]["vs_fork"] = rows[-1]["median_s"] / rows[-2]["median_s"]
    rows[-2]["vs_fork"] = 1.0
    rows.append(_row("ctrl-c while running", [s for _, s in running], 2.0))
    rows.append(_row("ctrl-c while starting", [s for _, s in starting], 2.0))
    return rows


if __name__ == "__main__":
    main(
        "startup",
        run,
        columns=[
            "what",
            "median_s",
            "min_s",
            "max_s",
            "cpu_median_s",
            "runs",
            "goal_s",
            "meets_goal",
            "vs_fork",
        ],
    )
