"""What a launcher does about each event of the link between hosts (``runtime.hostlink``):
the graph's policies (``on_host_lost``, the clock limit), a differing graph named by the
options that differ, a peer's stop passed on with its verdict."""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from typing import Any

from runtime.hosts import Hosts


@dataclass
class Act:
    """What the launcher does about one event: say ``lines``; if ``stop``, stop the graph
    (``echo``: tell the other hosts) with these codes."""

    lines: list[str]
    stop: str | None = None
    exit_code: int = 0
    verdict_code: int = 0
    echo: bool = True


def judge(event: tuple[Any, ...], hosts: Hosts) -> Act:
    """The launcher's answer to an event of :meth:`HostLink.events`, by the graph's policies."""
    kind, host, *args = event
    if kind == "joined":
        return Act([f"host {host!r} joined"])
    if kind == "graph_differs":
        theirs, ours, their_argv, our_argv = args
        lines = [
            f"host {host!r} runs another graph or run mode (sha256 {theirs[:12]}, here "
            f"{ours[:12]}): give every host the same graph file and the same options "
            "(--set/--swap/--only/--view/--lockstep/--record ...; only --host and --keys differ)"
        ]
        there, here = flags_differ(their_argv, our_argv)
        if there or here:
            lines.append(
                f"host {host!r} was started with {there or 'nothing'} that this host was not, "
                f"and this host with {here or 'nothing'} that it was not"
            )
        return Act(
            lines,
            f"host {host!r} runs another graph",
            exit_code=2,
        )
    if kind == "back":
        return Act([f"host {host!r} is back{' (a new launcher)' if args[0] else ''}"])
    if kind == "lost":
        policy = hosts.on_host_lost
        act = Act([f"host {host!r} lost: no heartbeat for {args[0]:.1f} s; on_host_lost: {policy}"])
        if policy == "stop":
            act.stop, act.exit_code, act.echo = f"host {host!r} lost", 1, False
        return act
    if kind == "clock":
        offset, rtt = args
        limit = hosts.max_clock_offset_secs
        act = Act(
            [
                f"clock offset to host {host!r}: {offset * 1e3:+.3f} ms "
                f"(round trip {rtt * 1e3:.3f} ms, limit {limit * 1e3:g} ms)"
            ]
        )
        if abs(offset) - rtt / 2 > limit:  # above the limit whatever the path's asymmetry
            act.lines.append(f"clocks differ by more than {limit * 1e3:g} ms: see docs/hosts.md")
            act.stop, act.exit_code = f"clock offset to host {host!r}", 1
        elif abs(offset) > limit:
            act.lines.append(f"warning: the clock offset to host {host!r} may exceed the limit")
        return act
    reason, code = args  # "stop"
    return Act([], f"host {host!r} stops: {reason}", verdict_code=code, echo=False)


def flags_differ(theirs: str, ours: str) -> tuple[str, str]:
    """The options (with their values) in one command line and not in the other, each way."""

    def options(argv: str) -> list[str]:
        try:
            words = shlex.split(argv)
        except ValueError:  # unbalanced quotes: the words as they are
            words = argv.split()
        out: list[str] = []
        for i, word in enumerate(words):
            if word.startswith("--"):
                value = words[i + 1] if i + 1 < len(words) else ""
                out.append(word if value.startswith("--") or not value else f"{word} {value}")
        return out

    mine, other = options(ours), options(theirs)
    return (
        " ".join(o for o in other if o not in mine),
        " ".join(o for o in mine if o not in other),
    )
