"""A WSG 50 emulator: the gripper's TCP protocol served from the simulator's jaws.

The frames, CRC and status codes are ``devices.wsg50``'s (the driver's own protocol
module); the jaws are a :class:`sim.gripper.GripperDynamics`, stepped by its owner
through :meth:`WSG50Server.stepped` (the world node, so contact, pressure and images
follow the emulated jaws; or this module's command line, with no object or a spring
standing in for one). Each TCP connection has one thread that answers its commands and
sends its auto-update streams when due.

What it answers: homing, move (stops on block: ``E_AXIS_BLOCKED``), grasp (the force
limit set by ``SET_FORCE_LIMIT``; ``E_CMD_FAILED`` when it closes without finding a
part), release, stop and fast stop (a running motion ends ``E_CMD_ABORTED``; after a
fast stop motion is ``E_ACCESS_DENIED`` until the fault is acknowledged), the force
limit, and opening, speed, force and grasping state once or streamed. Motion commands
answer ``E_CMD_PENDING`` and their final status once the jaws stop. A frame with a bad
CRC is answered ``E_CHECKSUM_ERROR``, an unknown command ``E_CMD_UNKNOWN``, a payload of
the wrong size ``E_CMD_FORMAT_ERROR``, a value out of range ``E_RANGE_ERROR``.

    python -m sim.wsg50_server --port 0      # prints the address it listens on
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import TypeVar

from devices.wsg50 import (
    ACK_PAYLOAD,
    AUTO_UPDATE,
    MOTION_COMMANDS,
    STREAMABLE,
    Cmd,
    Frame,
    FrameDecoder,
    FrameError,
    GraspState,
    Status,
    f32,
    response,
)
from sim.gripper import GripperDynamics
from sim.scene import GripperSpec

T = TypeVar("T")

_MOTION_KIND = {
    Cmd.HOMING: "home",
    Cmd.MOVE: "move",
    Cmd.GRASP: "grasp",
    Cmd.RELEASE: "release",
}
_MOVING_STATE = {
    Cmd.GRASP: GraspState.GRASPING,
    Cmd.RELEASE: GraspState.RELEASING,
    Cmd.MOVE: GraspState.POSITIONING,
    Cmd.HOMING: GraspState.POSITIONING,
}


class _Connection:
    """One client: its socket, its decoder and its streams (command -> period, due)."""

    def __init__(self, sock: socket.socket, peer: str) -> None:
        self.sock = sock
        self.peer = peer
        self.decoder = FrameDecoder()
        self.streams: dict[int, tuple[float, float]] = {}
        self.send_lock = threading.Lock()
        self.open = True

    def send(self, frame: bytes) -> None:
        if not self.open:
            return
        try:
            with self.send_lock:
                self.sock.sendall(frame)
        except OSError:
            self.open = False


class WSG50Server:
    """Serves the WSG 50 protocol for one :class:`GripperDynamics` (module docstring)."""

    def __init__(self, dynamics: GripperDynamics, *, host: str = "127.0.0.1", port: int = 0):
        self.dynamics = dynamics
        self.lock = threading.RLock()  # the jaws: commands, steps and reads
        self.force_limit_n = dynamics.spec.max_force_n
        self.fast_stopped = False
        self._motion: tuple[_Connection, int] | None = None
        self._last_motion = Cmd.HOMING
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.1)
        self.host, self.port = self._listener.getsockname()[:2]
        self._closing = threading.Event()
        self._threads: list[threading.Thread] = []
        self._connections: list[_Connection] = []
        self.frames_received = 0

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def start(self) -> WSG50Server:
        """Accept connections on a background thread."""
        thread = threading.Thread(target=self._accept_loop, name="wsg50-accept", daemon=True)
        thread.start()
        self._threads.append(thread)
        return self

    def drop_clients(self) -> int:
        """Close every client's connection and keep listening (a cable pulled and put back,
        a gripper that reboots); returns how many were open."""
        dropped = 0
        for conn in list(self._connections):
            if conn.open:
                conn.open = False
                with contextlib.suppress(OSError):
                    conn.sock.shutdown(socket.SHUT_RDWR)
                dropped += 1
        return dropped

    def close(self) -> None:
        self._closing.set()
        self._listener.close()
        for conn in list(self._connections):
            conn.open = False
            conn.sock.close()
        for thread in self._threads:
            thread.join(timeout=2.0)

    def stepped(self, step: Callable[[], T]) -> T:
        """Run ``step`` (which advances the jaws) under the lock, then end finished motions."""
        with self.lock:
            result = step()
            self._finish_motion()
            return result

    # -- the jaws ----------------------------------------------------------------------

    def grasp_state(self) -> GraspState:
        finger = self.dynamics.finger
        if self.fast_stopped:
            return GraspState.ERROR
        if finger.state == "fault":
            return GraspState.NO_PART
        if finger.state == "holding":
            return GraspState.HOLDING
        if finger.state == "moving":
            return _MOVING_STATE[self._last_motion]
        return GraspState.IDLE

    def _value(self, command: int) -> bytes:
        finger = self.dynamics.finger
        if command == Cmd.GET_OPENING:
            return f32(finger.width_m * 1e3)
        if command == Cmd.GET_SPEED:
            return f32(finger.speed_m_per_s * 1e3)
        if command == Cmd.GET_FORCE:
            return f32(finger.force_n)
        return struct.pack("<B", self.grasp_state())

    def _finish_motion(self) -> None:
        if self._motion is None:
            return
        conn, command = self._motion
        finger = self.dynamics.finger
        if command == Cmd.GRASP:
            if finger.state == "holding":
                status = Status.E_SUCCESS
            elif finger.state == "fault":
                status = Status.E_CMD_FAILED
            else:
                return
        elif finger.state == "moving":
            return
        else:
            reached = abs(finger.width_m - self.dynamics.target_m) < 1e-6
            status = Status.E_SUCCESS if reached else Status.E_AXIS_BLOCKED
        self._motion = None
        conn.send(response(command, status))

    def _abort_motion(self) -> None:
        if self._motion is not None:
            conn, command = self._motion
            self._motion = None
            conn.send(response(command, Status.E_CMD_ABORTED))

    # -- the protocol ------------------------------------------------------------------

    def handle(self, conn: _Connection, frame: Frame) -> bytes:
        """The immediate answer to one frame (a motion's final status comes later)."""
        self.frames_received += 1
        command, payload = frame.command, frame.payload
        with self.lock:
            if command in MOTION_COMMANDS:
                return self._motion_command(conn, command, payload)
            if command in STREAMABLE:
                if len(payload) != 3:
                    return response(command, Status.E_CMD_FORMAT_ERROR)
                flags, period_ms = struct.unpack("<BH", payload)
                if flags & AUTO_UPDATE and period_ms:
                    conn.streams[command] = (period_ms / 1e3, time.monotonic() + period_ms / 1e3)
                else:
                    conn.streams.pop(command, None)
                return response(command, Status.E_SUCCESS, self._value(command))
            if command in (Cmd.STOP, Cmd.FAST_STOP, Cmd.DISCONNECT):
                if payload:
                    return response(command, Status.E_NO_PARAM_EXPECTED)
                if command != Cmd.DISCONNECT:
                    self._abort_motion()
                    self.dynamics.command("stop", width_m=0.0, speed_m_per_s=0.0, force_n=0.0)
                    self.fast_stopped |= command == Cmd.FAST_STOP
                return response(command, Status.E_SUCCESS)
            if command == Cmd.ACK_FAULT:
                if payload != ACK_PAYLOAD:
                    return response(command, Status.E_CMD_FORMAT_ERROR)
                self.fast_stopped = False
                return response(command, Status.E_SUCCESS)
            if command == Cmd.SET_FORCE_LIMIT:
                if len(payload) != 4:
                    return response(command, Status.E_CMD_FORMAT_ERROR)
                (force,) = struct.unpack("<f", payload)
                if not 0 < force <= self.dynamics.spec.max_force_n:
                    return response(command, Status.E_RANGE_ERROR)
                self.force_limit_n = force
                return response(command, Status.E_SUCCESS)
            if command == Cmd.GET_FORCE_LIMIT:
                return response(command, Status.E_SUCCESS, f32(self.force_limit_n))
        return response(command, Status.E_CMD_UNKNOWN)

    def _motion_command(self, conn: _Connection, command: int, payload: bytes) -> bytes:
        spec = self.dynamics.spec
        if command == Cmd.HOMING:
            if len(payload) != 1:
                return response(command, Status.E_CMD_FORMAT_ERROR)
            width_mm, speed_mm = spec.max_width_m * 1e3, spec.max_speed_m_per_s * 1e3
        else:
            size = 9 if command == Cmd.MOVE else 8
            if len(payload) != size:
                return response(command, Status.E_CMD_FORMAT_ERROR)
            width_mm, speed_mm = struct.unpack_from("<2f", payload, size - 8)
        if self.fast_stopped:
            return response(command, Status.E_ACCESS_DENIED)
        if self._motion is not None:
            return response(command, Status.E_ALREADY_RUNNING)
        if not (0 <= width_mm <= spec.max_width_m * 1e3 and 0 < speed_mm):
            return response(command, Status.E_RANGE_ERROR)
        if speed_mm > spec.max_speed_m_per_s * 1e3:
            return response(command, Status.E_RANGE_ERROR)
        self.dynamics.command(
            _MOTION_KIND[Cmd(command)],
            width_m=width_mm / 1e3,
            speed_m_per_s=speed_mm / 1e3,
            force_n=self.force_limit_n,
        )
        self._last_motion = Cmd(command)
        self._motion = (conn, command)
        return response(command, Status.E_CMD_PENDING)

    # -- sockets -----------------------------------------------------------------------

    def _accept_loop(self) -> None:
        while not self._closing.is_set():
            try:
                sock, peer = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn = _Connection(sock, f"{peer[0]}:{peer[1]}")
            self._connections.append(conn)
            thread = threading.Thread(
                target=self._serve, args=(conn,), name=f"wsg50-{conn.peer}", daemon=True
            )
            thread.start()
            self._threads.append(thread)

    def _serve(self, conn: _Connection) -> None:
        try:
            while conn.open and not self._closing.is_set():
                now = time.monotonic()
                wait = min([due for _, due in conn.streams.values()], default=now + 0.05) - now
                readable, _, _ = select.select([conn.sock], [], [], max(0.0, min(wait, 0.05)))
                if readable:
                    data = conn.sock.recv(4096)
                    if not data:
                        break
                    for item in conn.decoder.feed(data):
                        if isinstance(item, FrameError):
                            conn.send(response(max(item.command, 0), Status.E_CHECKSUM_ERROR))
                            continue
                        conn.send(self.handle(conn, item))
                        if item.command == Cmd.DISCONNECT:
                            conn.open = False
                self._send_streams(conn)
        except OSError:
            pass  # the client went away; nothing to answer
        finally:
            conn.open = False
            conn.sock.close()
            with self.lock:
                if self._motion is not None and self._motion[0] is conn:
                    self._motion = None
            if conn in self._connections:
                self._connections.remove(conn)

    def _send_streams(self, conn: _Connection) -> None:
        now = time.monotonic()
        for command, (period, due) in list(conn.streams.items()):
            if now >= due:
                with self.lock:
                    value = self._value(command)
                conn.streams[command] = (period, max(due + period, now))
                conn.send(response(command, Status.E_SUCCESS, value))


def spring_part(width_m: float, stiffness_n_per_m: float) -> Callable[[float], float]:
    """The grip force of a part ``width_m`` wide that pushes back like a linear spring."""

    def force_at(opening_m: float) -> float:
        return max(0.0, (width_m - opening_m) * stiffness_n_per_m)

    return force_at


def step_in_real_time(
    server: WSG50Server,
    force_at: Callable[[float], float],
    *,
    period_secs: float,
    stop: threading.Event,
    duration_secs: float = float("inf"),
) -> None:
    """Step the server's jaws by the time that passed, every ``period_secs``, until ``stop``."""
    last = time.monotonic()
    end = last + duration_secs
    while last < end and not stop.wait(period_secs):
        now = time.monotonic()
        dt = now - last
        server.stepped(functools.partial(server.dynamics.step, dt, force_at))
        last = now


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sim.wsg50_server", description="Serve the WSG 50 TCP protocol."
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=1000, help="0: a free port")
    parser.add_argument("--rate-hz", type=float, default=200.0, help="how often the jaws step")
    parser.add_argument(
        "--part-width-mm",
        type=float,
        default=None,
        help="a part between the jaws (a linear spring); none: grasps find no part",
    )
    parser.add_argument("--part-stiffness-n-per-mm", type=float, default=5.0)
    parser.add_argument("--duration-secs", type=float, default=0.0, help="0: until stopped")
    args = parser.parse_args(argv)
    if not args.rate_hz > 0:
        parser.error(f"--rate-hz must be > 0, got {args.rate_hz}")
    dynamics = GripperDynamics(GripperSpec(), speed_limited=True)
    force_at = (
        spring_part(args.part_width_mm / 1e3, args.part_stiffness_n_per_mm * 1e3)
        if args.part_width_mm is not None
        else spring_part(0.0, 0.0)
    )
    try:
        server = WSG50Server(dynamics, host=args.host, port=args.port).start()
    except OSError as err:
        parser.error(f"cannot listen on {args.host}:{args.port}: {err}")
    print(f"WSG 50 emulator listening on {server.address}", flush=True)
    try:
        step_in_real_time(
            server,
            force_at,
            period_secs=1.0 / args.rate_hz,
            stop=threading.Event(),
            duration_secs=args.duration_secs if args.duration_secs > 0 else float("inf"),
        )
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
