"""The first code a node process runs, before anything heavy is imported.

``python -m runtime.child`` with the node's JSON spec on stdin (the launcher's pipe,
which also carries the run's control secret). In order:

1. take SIGTERM and SIGINT as "end now" (a quiet ``SystemExit``) while the node's
   modules import and the node is built; ``runtime.process`` then takes them over as
   "stop cleanly";
2. ask the kernel to send SIGTERM when the launcher dies (``PR_SET_PDEATHSIG``), then
   check the launcher is still the parent (it may have died before the request);
3. import ``runtime.process`` (numpy, ZeroMQ, the codec), then read the spec and run the
   node. The launcher starts these processes (:func:`start`) while it still checks the
   graph, so the imports every node shares overlap the check; a closed stdin with no
   spec (the check failed) ends the process quietly.

A node runs numpy's BLAS on one thread unless ``OPENBLAS_NUM_THREADS`` says otherwise: a
graph is a dozen processes on a few cores, so a BLAS thread pool per process only
oversubscribes them, and starting it costs each node about 60 ms of CPU at import.

Each node leads its own process group, and ends the rest of it on its way out (the
launcher also signals the whole group, and kills what is left of it once the node is
reaped), so a compiler the node started goes with it. A node that outlives its launcher
also removes the run folder, so even a SIGKILLed launcher leaves no process and no
``sbg-*`` folder behind.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

PR_SET_PDEATHSIG = 1
PROJECT_ROOT = Path(__file__).resolve().parent.parent
PARENT_ENV = "SBG_LAUNCHER_PID"
RUNDIR_ENV = "SBG_RUNDIR"


_signalled = False
GONE_WAIT_SECS = 0.2


def _end_now(signum: int, frame: Any) -> None:
    global _signalled
    _signalled = True
    raise SystemExit(128 + signum)


def launcher_gone(parent: int) -> bool:
    """Whether the launcher has died (or is dying: a zombie whose threads still exit)."""
    if os.getppid() != parent:
        return True
    try:
        state = Path(f"/proc/{parent}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


def _wait_launcher_gone(parent: int) -> bool:
    """After a signal: the kernel sends PR_SET_PDEATHSIG when the *thread* that started
    this process dies, which can be a moment before the rest of the launcher is gone."""
    end = time.monotonic() + (GONE_WAIT_SECS if _signalled else 0.0)
    while not launcher_gone(parent):
        if time.monotonic() >= end:
            return False
        time.sleep(0.01)
    return True


def die_with_parent(parent_pid: int) -> None:
    """Let the kernel end this process when ``parent_pid`` dies (Linux); exit if it has."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass  # not Linux: the heartbeat thread's parent check still covers it
    if os.getppid() != parent_pid:
        sys.exit(0)


def start(rundir: Path) -> subprocess.Popen[bytes]:
    """A node process of this launcher, importing while it waits for its spec on stdin.

    It leads its own process group: a Ctrl-C at the terminal reaches the launcher only,
    which stops the nodes in order.
    """
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PROJECT_ROOT), env.get("PYTHONPATH")]))
    env["PYTHONUNBUFFERED"] = "1"
    env[PARENT_ENV] = str(os.getpid())
    env[RUNDIR_ENV] = str(rundir)
    return subprocess.Popen(
        [sys.executable, "-m", "runtime.child"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        cwd=os.getcwd(),
        env=env,
        process_group=0,
    )


def release(prestarted: list[subprocess.Popen[bytes]]) -> None:
    """End node processes that were started but given no node to run."""
    for popen in prestarted:
        popen.terminate()  # they are still importing: SIGTERM ends that at once
    while prestarted:
        popen = prestarted.pop()
        assert popen.stdin is not None and popen.stdout is not None
        popen.stdin.close()
        popen.stdout.close()
        popen.wait()


def main() -> int:
    # The launcher's pid and the run folder come in the environment (neither is a secret),
    # so that even a child whose launcher died before writing its spec cleans up.
    parent = int(os.environ.pop(PARENT_ENV))
    rundir = os.environ.pop(RUNDIR_ENV, "")
    signal.signal(signal.SIGTERM, _end_now)
    signal.signal(signal.SIGINT, _end_now)
    try:
        die_with_parent(parent)
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        from runtime.process import main as run_node

        text = sys.stdin.read()
        if not text:
            return 0  # no spec: the graph check failed, or the launcher died first
        return run_node(json.loads(text))
    finally:
        # Leave nothing behind: what this node started (its own process group) ends with
        # it, and if the launcher is gone, so does the run folder.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if os.getpgrp() == os.getpid():
            os.killpg(0, signal.SIGTERM)
        if rundir and _wait_launcher_gone(parent):
            shutil.rmtree(rundir, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
