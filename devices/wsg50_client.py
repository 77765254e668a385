"""A WSG 50 client over TCP: commands with timeouts, streamed state, reconnection.

One reader thread receives every frame and hands it to whoever waits for that command
id (the immediate answer of a request, then the final status of a motion), or, for
value queries started with the auto-update option, stores it as the newest value.
Nothing blocks longer than its timeout:

* a request unanswered within ``timeout_secs`` raises :class:`WSGTimeout` (naming the
  command and any partial frame received) and the connection is reset, since a late
  answer could otherwise be taken for the next one;
* a dropped connection fails every waiter with :class:`ConnectionLost` at once; with
  ``reconnect`` the reader reconnects with back-off and restores the streams, and
  ``on_event`` reports the loss, each retry and the recovery.

Motion commands (homing, move, grasp, release) return a :class:`Motion` whose final
status arrives later; starting one while another runs raises, so stop first.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable

from devices.base import Device
from devices.wsg50 import (
    ACK_PAYLOAD,
    DEFAULT_PORT,
    MOTION_COMMANDS,
    STREAMABLE,
    Cmd,
    ConnectionLost,
    Frame,
    FrameDecoder,
    FrameError,
    GraspState,
    Status,
    StatusError,
    WSGTimeout,
    command_name,
    encode_frame,
    f32,
    move_payload,
    query_payload,
    read_f32,
)
from messages.errors import DeviceError

_POLL_SECS = 0.05  # how often the reader looks up from recv (closing, reconnecting)


class _Waiter:
    """One expected frame: the immediate answer or a motion's final status."""

    def __init__(self, command: int) -> None:
        self.command = command
        self.frame: Frame | None = None
        self.error: DeviceError | None = None
        self.done = threading.Event()

    def resolve(self, frame: Frame | None = None, error: DeviceError | None = None) -> None:
        self.frame, self.error = frame, error
        self.done.set()


class Motion:
    """A running motion command; :meth:`wait` returns its final status."""

    def __init__(self, client: WSG50Client, command: int, waiter: _Waiter | None) -> None:
        self.client = client
        self.command = command
        self._waiter = waiter  # None: the device reported success at once

    @property
    def done(self) -> bool:
        return self._waiter is None or self._waiter.done.is_set()

    def wait(self, timeout_secs: float) -> Status:
        """The final status; raises :class:`StatusError`, :class:`WSGTimeout`, ``ConnectionLost``."""
        if self._waiter is None:
            return Status.E_SUCCESS
        if not self._waiter.done.wait(timeout_secs):
            raise WSGTimeout(
                f"{self.client.where}: {command_name(self.command)} did not finish"
                f" within {timeout_secs:g} s"
            )
        return self.client._checked(self._waiter)


class WSG50Client(Device):
    """Talks to one WSG 50 (or its emulator); see the module docstring."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout_secs: float = 1.0,
        connect_timeout_secs: float = 5.0,
        reconnect: bool = True,
        backoff_secs: float = 0.1,
        backoff_max_secs: float = 2.0,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        for name, value in (
            ("timeout_secs", timeout_secs),
            ("connect_timeout_secs", connect_timeout_secs),
            ("backoff_secs", backoff_secs),
            ("backoff_max_secs", backoff_max_secs),
        ):
            if not value > 0:
                raise ValueError(f"`{name}` must be > 0, got {value!r}")
        self.host, self.port = host, int(port)
        self.where = f"WSG 50 at {host}:{port}"
        self.timeout_secs = timeout_secs
        self.connect_timeout_secs = connect_timeout_secs
        self.reconnect = reconnect
        self.backoff_secs, self.backoff_max_secs = backoff_secs, backoff_max_secs
        self.on_event = on_event or (lambda _msg: None)
        self._sock: socket.socket | None = None
        self._decoder = FrameDecoder()
        self._lock = threading.Lock()  # waiters, streams, latest values
        self._send_lock = threading.Lock()
        self._waiters: dict[int, deque[_Waiter]] = {}
        self._motion: Motion | None = None
        self._pending_final: dict[int, _Waiter] = {}  # a motion's final status, by command
        self._streams: dict[int, int] = {}  # command -> period ms
        self._latest: dict[int, tuple[bytes, float]] = {}  # command -> (data, monotonic)
        self._closing = threading.Event()
        self._leaving = False
        self._reader: threading.Thread | None = None
        self.reconnects = 0
        self.unexpected_frames = 0

    # -- lifecycle -------------------------------------------------------------------

    @property
    def is_connected(self) -> bool:
        return self._sock is not None

    def connect(self) -> None:
        """Connect (retrying with back-off up to ``connect_timeout_secs``), start the reader."""
        if self._reader is not None:
            return
        self._closing.clear()
        self._leaving = False
        self._sock = self._dial(self.connect_timeout_secs)
        self._reader = threading.Thread(target=self._read_loop, name="wsg50-reader", daemon=True)
        self._reader.start()

    def disconnect(self) -> None:
        """Announce the disconnect (best effort), close the socket, stop the reader."""
        self._leaving = True  # no reconnecting, no reports from here on
        if self._sock is not None:
            try:
                self.request(Cmd.DISCONNECT)
            except DeviceError:
                pass  # closing anyway: the device may already be gone
        self._closing.set()
        if self._reader is not None:
            self._reader.join(timeout=2.0)
            self._reader = None
        self._drop("disconnected by the client")

    # -- commands --------------------------------------------------------------------

    def request(self, command: int, payload: bytes = b"", *, timeout_secs: float = 0.0) -> Frame:
        """Send a command and return its answer (status E_SUCCESS or E_CMD_PENDING)."""
        waiter = self._expect(command)
        self._send(encode_frame(command, payload), waiter)
        self._wait(waiter, timeout_secs or self.timeout_secs)
        frame = waiter.frame
        assert frame is not None
        if frame.status not in (Status.E_SUCCESS, Status.E_CMD_PENDING):
            raise StatusError(command, frame.status, self.where)
        return frame

    def start_motion(self, command: int, payload: bytes = b"") -> Motion:
        """Start a motion; its final status comes through the returned :class:`Motion`."""
        if command not in MOTION_COMMANDS:
            raise ValueError(f"{command_name(command)} is not a motion command")
        with self._lock:
            if self._motion is not None and not self._motion.done:
                raise DeviceError(
                    f"{self.where}: {command_name(self._motion.command)} still running;"
                    " stop it before starting another motion"
                )
        frame = self.request(command, payload)
        motion = Motion(self, command, None)
        if frame.status == Status.E_CMD_PENDING:
            # The reader queued the final-status waiter when it saw E_CMD_PENDING.
            with self._lock:
                motion._waiter = self._pending_final.pop(command, None)
            if motion._waiter is None:
                raise ConnectionLost(
                    f"{self.where}: connection lost during {command_name(command)}"
                )
        with self._lock:
            self._motion = motion
        return motion

    def home(self) -> Motion:
        return self.start_motion(Cmd.HOMING, b"\x00")

    def move(self, width_m: float, speed_m_per_s: float) -> Motion:
        return self.start_motion(Cmd.MOVE, move_payload(width_m * 1e3, speed_m_per_s * 1e3))

    def grasp(self, width_m: float, speed_m_per_s: float) -> Motion:
        return self.start_motion(Cmd.GRASP, f32(width_m * 1e3, speed_m_per_s * 1e3))

    def release(self, width_m: float, speed_m_per_s: float) -> Motion:
        return self.start_motion(Cmd.RELEASE, f32(width_m * 1e3, speed_m_per_s * 1e3))

    def stop(self) -> None:
        self.request(Cmd.STOP)

    def fast_stop(self) -> None:
        self.request(Cmd.FAST_STOP)

    def ack_fault(self) -> None:
        self.request(Cmd.ACK_FAULT, ACK_PAYLOAD)

    def set_force_limit(self, force_n: float) -> None:
        self.request(Cmd.SET_FORCE_LIMIT, f32(force_n))

    def force_limit_n(self) -> float:
        return read_f32(self.request(Cmd.GET_FORCE_LIMIT).data, Cmd.GET_FORCE_LIMIT)

    def opening_m(self) -> float:
        return read_f32(self._query(Cmd.GET_OPENING), Cmd.GET_OPENING) / 1e3

    def speed_m_per_s(self) -> float:
        return read_f32(self._query(Cmd.GET_SPEED), Cmd.GET_SPEED) / 1e3

    def force_n(self) -> float:
        return read_f32(self._query(Cmd.GET_FORCE), Cmd.GET_FORCE)

    def grasp_state(self) -> GraspState:
        return GraspState(self._query(Cmd.GET_GRASP_STATE)[0])

    def _query(self, command: int) -> bytes:
        """A value: the streamed one when ``command`` streams (a one-shot query would end
        the stream: the device takes a query without auto-update as "stop sending")."""
        with self._lock:
            streaming = command in self._streams
        if streaming:
            if self._sock is None:
                raise ConnectionLost(f"{self.where}: not connected (reconnecting)")
            waiter = self._expect(command)  # the next streamed frame answers it
            self._wait(waiter, self.timeout_secs)
            assert waiter.frame is not None
            return waiter.frame.data
        return self.request(command, query_payload()).data

    def stream(self, command: int, period_ms: int) -> None:
        """Ask for ``command``'s value every ``period_ms`` (restored after a reconnect)."""
        if command not in STREAMABLE:
            raise ValueError(f"{command_name(command)} has no auto-update option")
        self.request(command, query_payload(period_ms))
        with self._lock:
            self._streams[command] = period_ms

    def latest(self, command: int) -> tuple[bytes, float] | None:
        """The newest value ``command`` reported (data after the status, monotonic secs)."""
        with self._lock:
            return self._latest.get(command)

    # -- internals -------------------------------------------------------------------

    def _expect(self, command: int) -> _Waiter:
        waiter = _Waiter(command)
        with self._lock:
            self._waiters.setdefault(command, deque()).append(waiter)
        return waiter

    def _wait(self, waiter: _Waiter, timeout_secs: float) -> None:
        if waiter.done.wait(timeout_secs):
            if waiter.error is not None:
                raise waiter.error
            return
        with self._lock:
            queue = self._waiters.get(waiter.command)
            if queue and waiter in queue:
                queue.remove(waiter)
        partial = self._decoder.pending
        detail = f"; {len(partial)} bytes of a partial frame: {partial.hex(' ')}" if partial else ""
        self._drop(f"no answer to {command_name(waiter.command)} within {timeout_secs:g} s")
        raise WSGTimeout(
            f"{self.where}: no answer to {command_name(waiter.command)}"
            f" within {timeout_secs:g} s{detail}"
        )

    def _checked(self, waiter: _Waiter) -> Status:
        if waiter.error is not None:
            raise waiter.error
        assert waiter.frame is not None
        status = waiter.frame.status
        if status != Status.E_SUCCESS:
            raise StatusError(waiter.command, status, self.where)
        return Status.E_SUCCESS

    def _send(self, frame: bytes, waiter: _Waiter | None = None) -> None:
        sock = self._sock
        if sock is None:
            err = ConnectionLost(f"{self.where}: not connected (reconnecting)")
            if waiter is not None:
                waiter.resolve(error=err)
                return
            raise err
        try:
            with self._send_lock:
                sock.sendall(frame)
        except OSError as exc:
            self._drop(f"send failed: {exc}")
            if waiter is None:
                raise ConnectionLost(f"{self.where}: send failed: {exc}") from exc

    def _dial(self, within_secs: float) -> socket.socket:
        deadline = time.monotonic() + within_secs
        delay = self.backoff_secs
        while True:
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout_secs)
            except OSError as exc:
                if time.monotonic() + delay > deadline or self._closing.is_set():
                    raise ConnectionLost(
                        f"{self.where}: cannot connect within {within_secs:g} s: {exc}"
                    ) from exc
                self._closing.wait(delay)
                delay = min(2 * delay, self.backoff_max_secs)
                continue
            sock.settimeout(_POLL_SECS)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return sock

    def _drop(self, why: str) -> None:
        """Close the socket and fail every waiter (the reader reconnects if enabled)."""
        with self._lock:
            sock, self._sock = self._sock, None
            waiters = [w for q in self._waiters.values() for w in q]
            waiters += list(self._pending_final.values())
            self._waiters.clear()
            self._pending_final.clear()
            self._decoder = FrameDecoder()
        if sock is None:
            return
        sock.close()
        err = ConnectionLost(f"{self.where}: connection lost: {why}")
        for waiter in waiters:
            waiter.resolve(error=err)
        if not self._leaving:
            self.on_event(f"{self.where}: connection lost: {why}")

    def _read_loop(self) -> None:
        while not self._closing.is_set():
            sock = self._sock
            if sock is None:
                if not self.reconnect or self._leaving or not self._redial():
                    return
                continue
            try:
                data = sock.recv(4096)
            except TimeoutError:
                continue
            except OSError as exc:
                self._drop(f"receive failed: {exc}")
                continue
            if not data:
                partial = self._decoder.pending
                mid = f" in the middle of a frame ({partial.hex(' ')})" if partial else ""
                self._drop(f"closed by the gripper{mid}")
                continue
            for item in self._decoder.feed(data):
                self._dispatch(item)

    def _redial(self) -> bool:
        """Reconnect with back-off until it works or the client closes; restore streams."""
        attempt = 0
        delay = self.backoff_secs
        while not self._closing.is_set():
            attempt += 1
            try:
                sock = self._dial(delay)
            except ConnectionLost as err:
                self.on_event(f"{err} (attempt {attempt}, next in {delay:g} s)")
                self._closing.wait(delay)
                delay = min(2 * delay, self.backoff_max_secs)
                continue
            with self._lock:
                self._sock = sock
                streams = dict(self._streams)
            self.reconnects += 1
            self.on_event(f"{self.where}: reconnected after {attempt} attempt(s)")
            for command, period_ms in streams.items():
                self._send(encode_frame(command, query_payload(period_ms)), self._expect(command))
            return True
        return False

    def _dispatch(self, item: Frame | FrameError) -> None:
        with self._lock:
            queue = self._waiters.get(item.command)
            waiter = queue.popleft() if queue else None
            if isinstance(item, Frame):
                self._note(item, waiter)
        if isinstance(item, FrameError):
            if waiter is not None:
                waiter.resolve(error=FrameError(f"{self.where}: {item}", item.command))
            else:
                self.on_event(f"{self.where}: {item}")
            return
        if waiter is not None:
            waiter.resolve(item)
        elif item.command not in STREAMABLE:
            self.unexpected_frames += 1
            self.on_event(f"{self.where}: unexpected {command_name(item.command)} frame")

    def _note(self, frame: Frame, waiter: _Waiter | None) -> None:
        """Under the lock: keep streamed values, queue a motion's final-status waiter."""
        if len(frame.payload) < 2:
            return
        status = frame.status
        if frame.command in STREAMABLE and status == Status.E_SUCCESS:
            self._latest[frame.command] = (frame.data, time.monotonic())
        if status == Status.E_CMD_PENDING and waiter is not None:
            final = _Waiter(frame.command)
            self._pending_final[frame.command] = final
            self._waiters.setdefault(frame.command, deque()).appendleft(final)


def float_value(entry: tuple[bytes, float] | None, command: int) -> float | None:
    """The float in a :meth:`WSG50Client.latest` entry, or None when there is none."""
    if entry is None:
        return None
    return read_f32(entry[0], command)


def u8_value(entry: tuple[bytes, float] | None) -> int | None:
    """The byte in a :meth:`WSG50Client.latest` entry, or None when there is none."""
    if entry is None or not entry[0]:
        return None
    return int(struct.unpack_from("<B", entry[0])[0])
