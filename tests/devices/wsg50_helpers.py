"""Helpers for the WSG 50 tests: a stepped emulator and a misbehaving fake gripper."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sim.gripper import GripperDynamics
from sim.scene import GripperSpec
from sim.wsg50_server import WSG50Server, spring_part, step_in_real_time


@contextmanager
def running_emulator(
    part_width_m: float = 0.05, *, port: int = 0, step_secs: float = 0.005
) -> Iterator[WSG50Server]:
    """An emulator on loopback whose jaws step in real time, a spring part between them."""
    dynamics = GripperDynamics(GripperSpec(), speed_limited=True)
    force_at = spring_part(part_width_m, 5000.0)
    server = WSG50Server(dynamics, port=port).start()
    stop = threading.Event()

    thread = threading.Thread(
        target=step_in_real_time,
        args=(server, force_at),
        kwargs={"period_secs": step_secs, "stop": stop},
        daemon=True,
    )
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join(timeout=2)
        server.close()


@contextmanager
def fake_gripper(behave: Callable[[socket.socket], None]) -> Iterator[int]:
    """A TCP server on a free port whose one connection is handled by ``behave``."""
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(5)
    port = listener.getsockname()[1]
    done = threading.Event()

    def serve() -> None:
        try:
            conn, _ = listener.accept()
        except OSError:
            return
        with conn:
            conn.settimeout(5)
            behave(conn)
            done.wait(5)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield port
    finally:
        done.set()
        listener.close()
        thread.join(timeout=6)


def recv_exactly(sock: socket.socket, size: int, timeout_secs: float = 5.0) -> bytes:
    """Read ``size`` bytes or fail after ``timeout_secs`` (never hangs a test)."""
    sock.settimeout(timeout_secs)
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise AssertionError(f"connection closed after {len(data)} of {size} bytes")
        data += chunk
    return data


def until(done: Callable[[], bool], timeout_secs: float = 60.0) -> bool:
    """Whether ``done()`` came true (polled): the client's threads get there on their own,
    however loaded the machine; the bound only makes one that never does a failure."""
    end = time.monotonic() + timeout_secs
    while not done():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True
