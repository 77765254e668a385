"""Hosts for the multi-host tests: key folders, graph files, and launchers run inside
network namespaces (``bench.netns``; skipped with the reason where they cannot be made),
and port ranges of this machine's loopback that no other run of the suite takes."""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from bench.netns import Namespace, namespaces, unavailable
from runtime.security import make_key

ROOT = Path(__file__).resolve().parents[2]
SYNTHETIC = "tests.synthetic_nodes:Synthetic"


def two_host_graph(keys: Path, *, policy: str = "stop", count: int = 60) -> dict[str, Any]:
    """A source on host ``a`` (10.77.0.1), a sink on ``b`` (10.77.0.2), CURVE keys in ``keys``."""
    return {
        "hosts": host_table(keys, ["a", "b"]),
        "on_host_lost": policy,
        "host_timeout_secs": 1.5,
        "nodes": {
            "src": {"impl": f"{SYNTHETIC}Source", "host": "a", "params": {"count": count}},
            "sink": {"impl": f"{SYNTHETIC}Sink", "host": "b", "inputs": {"tick": "src/tick"}},
        },
    }


def host_table(keys: Path, names: list[str]) -> dict[str, Any]:
    """Hosts ``names`` on 10.77.0.1, .2, ..., each with a new key pair in ``keys``."""
    return {
        name: {
            "address": f"10.77.0.{i + 1}",
            "ports": [24000, 24040],
            "public_key": make_key(keys, name).public,
        }
        for i, name in enumerate(names)
    }


# Below the kernel's ephemeral ports (32768 on): no `tcp://...:*` bind lands in a range.
_PORTS_FROM, _PORTS_TO, _BLOCK = 20000, 32000, 40  # ranges start on a block's first port
_held_ranges: list[int] = []  # lock files' descriptors, held until this process ends


def free_port_range(size: int) -> tuple[int, int]:
    """``[first, last]``: ``size`` ports of 127.0.0.1 free now, and this process's alone.

    A graph's ``hosts:`` table fixes its ports (each host's launcher binds them later),
    so they cannot be the kernel's pick on a bind to port 0. Instead each range is taken
    under a lock file (``$TMPDIR/sbg-test-ports/FIRST.lock``) that this process holds
    until it ends: two suites on one machine never pick the same range. Every port of it
    is bound once here, so one another program holds is not picked either; such a program
    could still take one between now and the launcher's bind, which nothing can prevent.
    """
    assert 0 < size <= _BLOCK, size
    folder = Path(tempfile.gettempdir()) / "sbg-test-ports"
    folder.mkdir(exist_ok=True)
    firsts = list(range(_PORTS_FROM, _PORTS_TO, _BLOCK))
    random.shuffle(firsts)
    for first in firsts:
        fd = os.open(folder / f"{first}.lock", os.O_CREAT | os.O_RDWR, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        if all(_bindable(port) for port in range(first, first + size)):
            _held_ranges.append(fd)
            return first, first + size - 1
        os.close(fd)
    raise AssertionError(f"no {size} free ports in a row on 127.0.0.1 in {_PORTS_FROM}..")


def _bindable(port: int) -> bool:
    with contextlib.closing(socket.socket()) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def write_graph(doc: dict[str, Any], path: Path) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.fixture
def netns() -> Iterator[list[Namespace]]:
    """Three namespaces on one bridge: 10.77.0.1, .2 and .3; always deleted."""
    reason = unavailable()
    if reason is not None:
        pytest.skip(f"no network namespaces here: {reason}")
    with namespaces(3) as spaces:
        yield spaces


class Launched:
    """``launch.py ARGS...`` started (in a namespace, if given), its output in a file."""

    def __init__(self, args: list[str | Path], log: Path, ns: Namespace | None = None) -> None:
        self.log = log
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        argv = [sys.executable, "launch.py", *map(str, args)]
        with open(log, "w") as out:
            self.proc = subprocess.Popen(
                ns.command(argv) if ns else argv,
                cwd=ROOT,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
            )

    @classmethod
    def host(cls, ns: Namespace, graph: Path, host: str, keys: Path, log: Path) -> Launched:
        """This host's launcher of ``graph``, in namespace ``ns``."""
        return cls([graph, "--host", host, "--keys", keys], log, ns)

    @property
    def text(self) -> str:
        return self.log.read_text()

    def wait_for(self, needle: str, timeout: float = 60.0) -> float:
        """Wait until the output has ``needle``; the time it was seen (``time.monotonic``)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if needle in self.text:
                return time.monotonic()
            if self.proc.poll() is not None and needle not in self.text:
                break
            time.sleep(0.05)
        raise AssertionError(f"{needle!r} not in the output:\n{self.text[-3000:]}")

    def finish(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"the launcher did not end:\n{self.text[-3000:]}") from None

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def launched() -> Iterator[list[Launched]]:
    """Launchers a test starts (append them): killed at the end if still running."""
    started: list[Launched] = []
    yield started
    for item in started:
        item.kill()
