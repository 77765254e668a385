"""Hosts made as Linux network namespaces on this machine, for tests and benchmarks.

``namespaces(n)`` makes ``n`` namespaces, each with its loopback and one veth interface
on ``10.77.0.(i+1)/24``, the veths' other ends on a bridge in a hub namespace of their
own (nothing is added to this machine's own network), and deletes them all on the way
out, whatever happened (and, first, those of a process killed before it could). Needs root and ``ip`` (iproute2); :func:`unavailable` says why
not when it cannot work here.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

from runtime.security import KeyPair

SUBNET = "10.77.0"
CLONE_NEWNET = 0x40000000
STALE = re.compile(r"sb(\d+)(?:hub|h\d+)")  # the names namespaces() gives


@dataclass(frozen=True)
class Namespace:
    name: str
    address: str

    def command(self, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside this namespace."""
        return ["ip", "netns", "exec", self.name, *argv]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


def _remove_stale() -> None:
    """Delete namespaces this module made in a process that is gone (one killed before it
    could clean up): their names carry the pid that made them."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=30)
    for line in listed.stdout.splitlines():
        found = STALE.fullmatch(line.split(" ")[0])
        if found is None:
            continue
        try:
            os.kill(int(found.group(1)), 0)
        except ProcessLookupError:
            subprocess.run(["ip", "netns", "del", found.group(0)], capture_output=True, timeout=30)
        except PermissionError:
            pass  # alive, another user's


def unavailable() -> str | None:
    """Why namespaces cannot be made here (not root, no ``ip``, refused), or None."""
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns add)"
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    probe = f"sbgprobe{os.getpid()}"
    try:
        _ip("netns", "add", probe)
    except subprocess.CalledProcessError as err:
        return f"`ip netns add` fails here: {err.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=30)
    return None


@contextmanager
def namespaces(count: int) -> Iterator[list[Namespace]]:
    """``count`` namespaces on one bridge (see the module's docstring)."""
    _remove_stale()
    tag = f"sb{os.getpid()}"
    hub = f"{tag}hub"
    made: list[str] = []
    try:
        _ip("netns", "add", hub)
        made.append(hub)
        _ip("-n", hub, "link", "add", "br0", "type", "bridge")
        _ip("-n", hub, "link", "set", "br0", "up")
        spaces = []
        for i in range(count):
            ns = Namespace(f"{tag}h{i}", f"{SUBNET}.{i + 1}")
            _ip("netns", "add", ns.name)
            made.append(ns.name)
            _ip("-n", ns.name, "link", "set", "lo", "up")
            veth, port = f"{tag}v{i}", f"{tag}p{i}"
            peer = ["peer", "name", port, "netns", hub]
            _ip("link", "add", veth, "netns", ns.name, "type", "veth", *peer)
            _ip("-n", hub, "link", "set", port, "master", "br0")
            _ip("-n", hub, "link", "set", port, "up")
            _ip("-n", ns.name, "addr", "add", f"{ns.address}/24", "dev", veth)
            _ip("-n", ns.name, "link", "set", veth, "up")
            spaces.append(ns)
        yield spaces
    finally:
        for name in reversed(made):
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)


def enter(name: str) -> None:
    """Move this process into namespace ``name``: call it first thing in a new process,
    before any thread (ZeroMQ's I/O threads) is started, so they all start inside."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(f"/var/run/netns/{name}", os.O_RDONLY)
    try:
        if libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns into {name}: {os.strerror(err)}")
    finally:
        os.close(fd)


@dataclass(frozen=True)
class Net:
    """Where a benchmark's two processes run: namespaces ``spaces`` (source, sink) and,
    for CURVE, the (server, client) key pairs."""

    spaces: tuple[str, str]
    keys: tuple[KeyPair, KeyPair] | None = None
