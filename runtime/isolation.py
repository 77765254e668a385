"""Keeping a run to this user and this machine: its private folder, loopback hosts.

Each run's ``ipc://`` endpoints live in a folder only its user can enter,
``$TMPDIR/sbg-PID-*``. The launcher removes it on every exit it sees; when the launcher
is SIGKILLed, its nodes (which die with it) remove it on their way out
(``runtime.child``), and the next launcher sweeps folders of this user whose PID is gone.

Frames and control messages on loopback and ``ipc://`` travel unencrypted, so the graph
check (``runtime.graph``) lets a node bind TCP off loopback only in a graph whose
``hosts:`` table gives CURVE keys (``runtime.hosts``, ``runtime.security``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from runtime.graph import RUNDIR_PREFIX


def make_rundir() -> Path:
    """A fresh private run folder (after sweeping the stale ones of this user)."""
    sweep_stale_rundirs()
    return Path(tempfile.mkdtemp(prefix=f"{RUNDIR_PREFIX}{os.getpid()}-"))


def user_rundirs() -> Iterator[tuple[Path, bool]]:
    """This user's ``sbg-PID-*`` run folders, each with whether its launcher PID exists."""
    for path in Path(tempfile.gettempdir()).glob(f"{RUNDIR_PREFIX}*-*"):
        pid = path.name[len(RUNDIR_PREFIX) :].partition("-")[0]
        try:
            if not pid.isdigit() or path.stat().st_uid != os.getuid():
                continue
            os.kill(int(pid), 0)
        except ProcessLookupError:
            yield path, False
        except OSError:
            continue
        else:
            yield path, True


def sweep_stale_rundirs() -> None:
    """Remove ``sbg-PID-*`` folders of this user whose launcher PID no longer exists."""
    for path, alive in user_rundirs():
        if not alive:
            shutil.rmtree(path, ignore_errors=True)
