"""The launcher's node processes: what it knows of each, and starting, reaping and
signalling them.

A node process (a fork of the launcher's fork server, ``runtime.child``) leads its own
process group (a Ctrl-C at the terminal reaches the launcher only, which stops the nodes
in order), reads its JSON spec on stdin (the run's secret with it: never on a command
line or in the environment), and its output is read line by line by a thread and printed
with the node's name.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import IO, Any, Literal

from runtime import counters
from runtime.child import NodeProcess
from runtime.counters import add_stats
from runtime.graph import NodeSpec

# A node process's life, as the launcher sees it (mypy checks every assignment).
ProcState = Literal["new", "hello", "ready", "running", "exited", "waiting_restart", "failed"]


@dataclass
class Proc:
    spec: NodeSpec
    process: NodeProcess | None = None
    rid: bytes | None = None  # the ROUTER id of the node's main control socket
    spawned_at: float = 0.0
    endpoint: str | None = None
    state: ProcState = "new"
    restarts: int = 0
    restart_at: float = 0.0
    last_heartbeat: float = 0.0
    busy_secs: float = 0.0
    cpu_secs: float = 0.0
    exit_codes: list[int] = field(default_factory=list)
    stats: dict[str, Any] = field(default_factory=dict)
    stats_at: float = 0.0
    stats_base: dict[str, Any] = field(default_factory=dict)
    counts_published: dict[str, int] = field(default_factory=dict)
    counts_received: dict[str, int] = field(default_factory=dict)
    signalled: set[int] = field(default_factory=set)  # what the launcher sent this incarnation
    counts_held: dict[str, int] = field(default_factory=dict)  # an ordered fan-in's, per port
    # Waiting for its other ordered inputs (``runtime.ordering``), per port.
    counts_pending: dict[str, int] = field(default_factory=dict)
    released: bool = False  # told to handle what it holds (lockstep), since its last counts


def spawn(
    proc: Proc,
    process: NodeProcess,
    child_spec: dict[str, Any],
    say: Callable[[str, str], None],
) -> None:
    """Make ``process`` (new from ``runtime.child.Starter``) ``proc``'s node:
    ``child_spec`` on its stdin, its lines to ``say``."""
    try:
        process.stdin.write(json.dumps(child_spec).encode())
        process.stdin.close()
    except BrokenPipeError:
        pass  # it died already: reaped and reported like any failed node
    threading.Thread(target=_pump, args=(proc, process.stdout, say), daemon=True).start()
    proc.process = process
    proc.rid = None
    proc.signalled = set()
    proc.state = "new"
    proc.spawned_at = proc.last_heartbeat = time.monotonic()
    proc.busy_secs = 0.0
    proc.stats_base = add_stats(proc.stats_base, proc.stats)
    proc.stats = {}


def _pump(proc: Proc, stream: IO[bytes], say: Callable[[str, str], None]) -> None:
    for raw in iter(stream.readline, b""):
        line = raw.decode(errors="replace").rstrip("\n")
        say(line, proc.spec.name)
    stream.close()


def reap(proc: Proc) -> int | None:
    """``proc``'s exit code if its process has ended (its CPU time added), else None.

    Whatever the node started and left behind is killed with it (the process group
    outlives its leader).
    """
    assert proc.process is not None
    try:
        pid, status, usage = os.wait4(proc.process.pid, os.WNOHANG)
    except ChildProcessError:
        pid, status, usage = proc.process.pid, 0, None
    if pid == 0:
        return None
    if usage is not None:
        proc.cpu_secs += usage.ru_utime + usage.ru_stime
    code = os.waitstatus_to_exitcode(status)
    proc.process.returncode = code
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.exit_codes.append(code)
    return code


def signal_group(proc: Proc, signum: int) -> None:
    """Signal a node's process group: the node and any process it started (a compiler)."""
    if proc.process is not None and proc.process.returncode is None:
        proc.signalled.add(int(signum))
        try:
            os.killpg(proc.process.pid, signum)
        except (ProcessLookupError, PermissionError):
            pass


def ended_by_launcher(proc: Proc, code: int) -> bool:
    """Whether a non-zero exit code is a signal the launcher sent this incarnation, as the
    kernel (-N) or the node's quiet handler before it runs (128 + N) reports it."""
    return (-code if code < 0 else code - 128) in proc.signalled


def not_back(procs: Iterable[Proc]) -> list[Proc]:
    """Nodes that failed and have not come back: a back-off still to wait, or a restart
    not ready yet (hung in ``setup()``)."""
    return [
        p for p in procs if p.restarts and p.state in ("waiting_restart", "new", "hello", "ready")
    ]


def exit_reason(code: int) -> str:
    return f"signal {-code}" if code < 0 else f"exit code {code}"


def counts(
    procs: Mapping[str, Proc],
) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
    """These nodes' newest lockstep counts: published per topic, received per node/port,
    and held (received, not handled yet) per node/port."""
    items = procs.items()
    published = {t: n for _, p in items for t, n in p.counts_published.items()}
    received = {f"{x}/{port}": n for x, p in items for port, n in p.counts_received.items()}
    held = {f"{x}/{port}": n for x, p in items for port, n in p.counts_held.items() if n}
    return published, received, held


def pending(procs: Mapping[str, Proc]) -> dict[str, int]:
    """What these nodes hold in stamp order (``runtime.ordering``), per node/port."""
    return {f"{x}/{port}": n for x, p in procs.items() for port, n in p.counts_pending.items() if n}


def totals(procs: Mapping[str, Proc]) -> dict[str, int]:
    """What these nodes published, per topic, every incarnation summed."""
    stats = [add_stats(p.stats_base, p.stats) for p in procs.values()]
    return {t: n for st in stats for t, n in st.get("published", {}).items()}


def table(procs: Mapping[str, Proc], elapsed_secs: float) -> str:
    """The end-of-run table of these nodes (every incarnation's counts summed)."""
    stats = {name: add_stats(p.stats_base, p.stats) for name, p in procs.items()}
    nodes = {
        name: {
            "restarts": p.restarts,
            "cpu_secs": p.cpu_secs,
            "exit": p.exit_codes[-1] if p.exit_codes else None,
        }
        for name, p in procs.items()
    }
    return counters.table(stats, nodes, elapsed_secs)


def stop(
    procs: list[Proc],
    graces: tuple[float, float],
    tell: Callable[[Proc], None],
    serve: Callable[[], object],
    say: Callable[[str], None],
) -> None:
    """Stop ``procs``: ask each (``tell``; SIGTERM to one still importing, which cannot hear
    it yet), SIGTERM those still running after ``graces[0]`` s, SIGKILL those still running
    ``graces[1]`` s later; ``serve()`` serves the launcher for a moment (50 ms) meanwhile."""
    live = [p for p in procs if p.process is not None and p.process.returncode is None]
    for proc in live:
        if proc.rid is None:
            signal_group(proc, signal.SIGTERM)
        else:
            tell(proc)
    for signum, grace in ((None, graces[0]), (signal.SIGTERM, graces[1]), (signal.SIGKILL, 5.0)):
        live = [p for p in procs if p.process is not None and p.process.returncode is None]
        if not live:
            break
        if signum is not None:
            say(f"{len(live)} node(s) still running: sending {signum.name}")
            for proc in live:
                signal_group(proc, signum)
        end = time.monotonic() + grace
        while time.monotonic() < end and any(p.process.returncode is None for p in live):  # type: ignore[union-attr]
            serve()
