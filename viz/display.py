"""Whether a viewer window can open here, asked before anything starts one.

Rerun's window needs a display; without one it prints its log and exits, and a stream
into it waits for good. The command line and the viewer node ask :func:`has_display`
first and stop with :class:`NoDisplay`, one line saying what to use instead.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

NO_DISPLAY = "no display here (DISPLAY and WAYLAND_DISPLAY are unset), so no Rerun window"


class NoDisplay(OSError):
    """A viewer window was asked for on a machine without a display."""


def has_display(environ: Mapping[str, str] | None = None) -> bool:
    """Always on macOS and Windows; elsewhere when ``DISPLAY`` (X11) or
    ``WAYLAND_DISPLAY``/``WAYLAND_SOCKET`` (Wayland) is set."""
    if sys.platform in ("darwin", "win32"):
        return True
    env = os.environ if environ is None else environ
    return any(env.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def require_display(instead: str) -> None:
    """Raise :class:`NoDisplay` (its message ends with ``instead``) when there is none."""
    if not has_display():
        raise NoDisplay(f"{NO_DISPLAY}: {instead}")
