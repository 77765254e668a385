"""The entry point into the command line, ``cli`` (``python launch.py --help`` lists its
commands; ``softbubble``, the installed command, is the same)."""

from __future__ import annotations

import os
import signal


def _interrupted(signum: int, frame: object) -> None:
    """Ctrl-C or SIGTERM outside a running graph: end now, quietly, with 128 + N.

    Installed before anything else is imported, so a signal during start-up is never a
    traceback; the launcher installs its own handlers while it supervises a graph. Once
    ending, further signals are ignored (see :func:`_end`).
    """
    _end(128 + signum)


def _end(code: object) -> None:
    """Exit with ``code``, deaf to SIGINT and SIGTERM from now on: Python gives a signal
    its default action again late in its shutdown, so a quick second or third Ctrl-C
    would otherwise kill the process by SIGINT (exit -2) instead of the code it chose."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise SystemExit(code)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, _interrupted)
    signal.signal(signal.SIGTERM, _interrupted)

# Nodes are forks of the launcher (runtime.child): numpy's BLAS on one thread in each
# unless the user says otherwise (a dozen processes share a few cores). Set before
# anything imports numpy, for `python launch.py` and the `softbubble` command alike.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from cli.main import main  # noqa: E402 - after the signal handlers and BLAS, on purpose

__all__ = ["main"]

if __name__ == "__main__":
    _end(main())
