"""Run the real launcher in a subprocess with a private temp folder, and poke at it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from tests.runtime.conftest import alive, children_of, is_node, still_alive
from tests.synthetic_nodes import IMPLS

ROOT = Path(__file__).resolve().parents[2]
FAULTS = "tests.faults.fault_nodes"


class Run:
    """One launcher process: its output (read on a thread), its children, its temp folder."""

    def __init__(self, tmp_path: Path, nodes: dict, *args: str, argv: list[str] | None = None):
        self.tmpdir = tmp_path / "tmp"
        self.tmpdir.mkdir(exist_ok=True)
        graph = tmp_path / "graph.yaml"
        graph.write_text(yaml.safe_dump({"nodes": nodes}))
        env = dict(os.environ, PYTHONPATH=str(ROOT), TMPDIR=str(self.tmpdir))
        self.proc = subprocess.Popen(
            [sys.executable, str(ROOT / "launch.py"), *(argv or [str(graph), *args])],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self.kids: set[int] = set()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def log(self) -> str:
        return "".join(self.lines)

    def note_kids(self) -> list[int]:
        """The launcher's node processes now (every child, its fork server too, is
        remembered for :meth:`leftovers`)."""
        kids = children_of(self.proc.pid)
        self.kids.update(kids)
        return [k for k in kids if is_node(k)]

    def wait_for(self, text: str, timeout: float = 60) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.note_kids()
            if text in self.log:
                return
            if self.proc.poll() is not None:
                self._reader.join(timeout=5)
                if text in self.log:
                    return
                break
            time.sleep(0.02)
        raise AssertionError(f"{text!r} not seen; output:\n{self.log}")

    def wait_for_kids(self, n: int, timeout: float = 30) -> list[int]:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            kids = self.note_kids()
            if len(kids) >= n:
                return kids
            time.sleep(0.01)
        raise AssertionError(f"{n} children not seen; output:\n{self.log}")

    def wait_for_handlers(self, timeout: float = 30) -> None:
        """Until the launcher catches SIGINT and SIGTERM (its Python code has begun: before
        that the interpreter itself is starting, and a signal ends it the default way)."""
        want = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            status = Path(f"/proc/{self.proc.pid}/status").read_text()
            caught = int(
                next(ln for ln in status.splitlines() if ln.startswith("SigCgt:")).split()[1], 16
            )
            if caught & want == want:
                return
            time.sleep(0.005)
        raise AssertionError("the launcher never caught SIGINT and SIGTERM")

    def signal_and_wait(self, signum: int, timeout: float = 30) -> int:
        """Send ``signum`` to the launcher; its exit code."""
        self.note_kids()
        self.proc.send_signal(signum)
        return self.finish(timeout)

    def finish(self, timeout: float = 60) -> int:
        code = self.proc.wait(timeout=timeout)
        self._reader.join(timeout=5)
        return code

    def leftovers(self) -> tuple[list[int], list[str]]:
        """Children still alive and files left in the temp folder, once every child has
        ended (a node of a killed launcher removes the run folder before it exits)."""
        return still_alive(self.kids), sorted(p.name for p in self.tmpdir.iterdir())

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)
        for kid in self.kids:
            if alive(kid):
                os.kill(kid, signal.SIGKILL)


@pytest.fixture
def run(tmp_path: Path):
    runs: list[Run] = []

    def start(nodes: dict, *args: str, argv: list[str] | None = None) -> Run:
        r = Run(tmp_path, nodes, *args, argv=argv)
        runs.append(r)
        return r

    yield start
    for r in runs:
        r.kill()


def ticker(**params: float | str) -> dict:
    return {"impl": f"{FAULTS}:Ticker", "params": params}


def sink(topic: str, **extra: object) -> dict:
    # The launcher subprocess registers only production nodes: the test sink by module:Class.
    return {"impl": IMPLS["synthetic.sink"], "inputs": {"tick": topic}, **extra}
