"""The first code a node process runs, before anything heavy is imported.

``python -m runtime.child`` with the node's JSON spec on stdin (the launcher's pipe,
which also carries the run's control secret). In order:

1. read the spec;
2. ask the kernel to send SIGTERM when the launcher dies (``PR_SET_PDEATHSIG``), then
   check the launcher is still the parent (it may have died before the request);
3. take SIGTERM and SIGINT as "end now" (a quiet ``SystemExit``) while the node's
   modules import and the node is built; ``runtime.process`` then takes them over as
   "stop cleanly";
4. import ``runtime.process`` and run the node.

A node that outlives its launcher removes the run folder on its way out, so even a
SIGKILLed launcher leaves no ``sbg-*`` folder behind.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import signal
import sys
from typing import Any

PR_SET_PDEATHSIG = 1


def _end_now(signum: int, frame: Any) -> None:
    raise SystemExit(128 + signum)


def die_with_parent(parent_pid: int) -> None:
    """Let the kernel end this process when ``parent_pid`` dies (Linux); exit if it has."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass  # not Linux: the heartbeat thread's parent check still covers it
    if os.getppid() != parent_pid:
        sys.exit(0)


def main() -> int:
    spec = json.loads(sys.stdin.read())
    parent = spec["parent_pid"]
    signal.signal(signal.SIGTERM, _end_now)
    signal.signal(signal.SIGINT, _end_now)
    try:
        die_with_parent(parent)
        from runtime.process import main as run_node

        return run_node(spec)
    finally:
        if os.getppid() != parent and spec.get("rundir"):
            shutil.rmtree(spec["rundir"], ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
