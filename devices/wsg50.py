"""The Schunk WSG 50's binary TCP protocol: frames, CRC, status codes, commands.

A frame is ``AA AA AA``, the command id (u8), the payload length (u16), the payload and
a CRC16 (u16); every number little-endian, floats IEEE-754 single. The CRC runs over
preamble, header and payload with a table built from the polynomial 0x1021 and the
update ``crc = T[(crc ^ byte) & 0xFF] ^ (crc >> 8)`` from 0xFFFF, so the CRC over a whole
frame (checksum included) is 0. A response carries the command's id and starts with a
u16 status; a motion command answers ``E_CMD_PENDING`` at once and its final status when
the motion ends. docs/devices.md lists the facts and their public source.

This module is pure (sockets and threads only): the client is :mod:`devices.wsg50_client`,
the emulator ``sim.wsg50_server`` imports the protocol from here.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from messages.errors import DeviceError
from messages.types import GripperStatus

PREAMBLE = b"\xaa\xaa\xaa"
HEADER_SIZE = 6  # preamble, id, u16 length
MAX_PAYLOAD = 4096  # a WSG frame is far shorter; a bigger length means a corrupt header
DEFAULT_PORT = 1000


class Cmd(enum.IntEnum):
    """Command ids of the WSG command set used here."""

    DISCONNECT = 0x07
    HOMING = 0x20
    MOVE = 0x21
    STOP = 0x22
    FAST_STOP = 0x23
    ACK_FAULT = 0x24
    GRASP = 0x25
    RELEASE = 0x26
    SET_FORCE_LIMIT = 0x32
    GET_FORCE_LIMIT = 0x33
    GET_GRASP_STATE = 0x41
    GET_OPENING = 0x43
    GET_SPEED = 0x44
    GET_FORCE = 0x45


MOTION_COMMANDS = frozenset({Cmd.HOMING, Cmd.MOVE, Cmd.GRASP, Cmd.RELEASE})
# Value queries that take the auto-update option: flags byte, u16 period (ms).
STREAMABLE = frozenset({Cmd.GET_GRASP_STATE, Cmd.GET_OPENING, Cmd.GET_SPEED, Cmd.GET_FORCE})
AUTO_UPDATE = 0x01  # flags bit 0: send the value every period
ACK_PAYLOAD = b"ack"  # acknowledge fault takes the three letters as its payload


class Status(enum.IntEnum):
    """Status codes of the WSG command set (u16, first two bytes of every response)."""

    E_SUCCESS = 0
    E_NOT_AVAILABLE = 1
    E_NO_SENSOR = 2
    E_NOT_INITIALIZED = 3
    E_ALREADY_RUNNING = 4
    E_FEATURE_NOT_SUPPORTED = 5
    E_INCONSISTENT_DATA = 6
    E_TIMEOUT = 7
    E_READ_ERROR = 8
    E_WRITE_ERROR = 9
    E_INSUFFICIENT_RESOURCES = 10
    E_CHECKSUM_ERROR = 11
    E_NO_PARAM_EXPECTED = 12
    E_NOT_ENOUGH_PARAMS = 13
    E_CMD_UNKNOWN = 14
    E_CMD_FORMAT_ERROR = 15
    E_ACCESS_DENIED = 16
    E_ALREADY_OPEN = 17
    E_CMD_FAILED = 18
    E_CMD_ABORTED = 19
    E_INVALID_HANDLE = 20
    E_NOT_FOUND = 21
    E_NOT_OPEN = 22
    E_IO_ERROR = 23
    E_INVALID_PARAMETER = 24
    E_INDEX_OUT_OF_BOUNDS = 25
    E_CMD_PENDING = 26
    E_OVERRUN = 27
    E_RANGE_ERROR = 28
    E_AXIS_BLOCKED = 29
    E_FILE_EXISTS = 30


_MEANING = {
    Status.E_SUCCESS: "no error",
    Status.E_NOT_AVAILABLE: "device, service or data not available",
    Status.E_NO_SENSOR: "no sensor connected",
    Status.E_NOT_INITIALIZED: "not initialized (home the gripper first)",
    Status.E_ALREADY_RUNNING: "already running",
    Status.E_FEATURE_NOT_SUPPORTED: "feature not supported",
    Status.E_INCONSISTENT_DATA: "inconsistent parameters",
    Status.E_TIMEOUT: "timeout in the device",
    Status.E_READ_ERROR: "read error in the device",
    Status.E_WRITE_ERROR: "write error in the device",
    Status.E_INSUFFICIENT_RESOURCES: "insufficient resources",
    Status.E_CHECKSUM_ERROR: "the device saw a checksum error",
    Status.E_NO_PARAM_EXPECTED: "no parameter expected",
    Status.E_NOT_ENOUGH_PARAMS: "not enough parameters",
    Status.E_CMD_UNKNOWN: "unknown command",
    Status.E_CMD_FORMAT_ERROR: "command format error",
    Status.E_ACCESS_DENIED: "access denied (a fast stop or fault must be acknowledged)",
    Status.E_ALREADY_OPEN: "already open",
    Status.E_CMD_FAILED: "command failed (for a grasp: no part found)",
    Status.E_CMD_ABORTED: "command aborted (stopped)",
    Status.E_INVALID_HANDLE: "invalid handle",
    Status.E_NOT_FOUND: "not found",
    Status.E_NOT_OPEN: "not open",
    Status.E_IO_ERROR: "I/O error",
    Status.E_INVALID_PARAMETER: "invalid parameter",
    Status.E_INDEX_OUT_OF_BOUNDS: "index out of bounds",
    Status.E_CMD_PENDING: "command pending",
    Status.E_OVERRUN: "overrun",
    Status.E_RANGE_ERROR: "parameter out of range",
    Status.E_AXIS_BLOCKED: "axis blocked",
    Status.E_FILE_EXISTS: "file exists",
}


class GraspState(enum.IntEnum):
    """The gripper's grasping state (``GET_GRASP_STATE``, one byte)."""

    IDLE = 0
    GRASPING = 1
    NO_PART = 2
    PART_LOST = 3
    HOLDING = 4
    RELEASING = 5
    POSITIONING = 6
    ERROR = 7


# GripperState.state for each grasping state.
STATE_NAMES: dict[int, GripperStatus] = {
    GraspState.IDLE: "idle",
    GraspState.GRASPING: "moving",
    GraspState.NO_PART: "fault",
    GraspState.PART_LOST: "fault",
    GraspState.HOLDING: "holding",
    GraspState.RELEASING: "moving",
    GraspState.POSITIONING: "moving",
    GraspState.ERROR: "fault",
}


class FrameError(DeviceError):
    """Bytes on the wire that are not a valid frame (bad CRC, absurd length)."""

    def __init__(self, message: str, command: int = -1) -> None:
        super().__init__(message)
        self.command = command


class WSGTimeout(DeviceError):
    """The gripper did not answer within the timeout."""


class ConnectionLost(DeviceError):
    """The TCP connection to the gripper closed or failed."""


class StatusError(DeviceError):
    """The gripper answered a command with an error status."""

    def __init__(self, command: int, status: int, where: str = "WSG 50") -> None:
        self.command = command
        self.status = status
        super().__init__(f"{where}: {command_name(command)} failed: {status_text(status)}")


def command_name(command: int) -> str:
    """``GRASP (0x25)``; unknown ids print as hex."""
    try:
        return f"{Cmd(command).name} (0x{command:02x})"
    except ValueError:
        return f"command 0x{command:02x}"


def status_text(status: int) -> str:
    """``E_AXIS_BLOCKED (29): axis blocked``."""
    try:
        code = Status(status)
    except ValueError:
        return f"unknown status {status}"
    return f"{code.name} ({status}): {_MEANING[code]}"


def _crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return tuple(table)


_TABLE = _crc_table()


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """The WSG's CRC16 of ``data`` (see the module docstring)."""
    for byte in data:
        crc = _TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)
    return crc


def encode_frame(command: int, payload: bytes = b"") -> bytes:
    """A complete frame: preamble, id, length, payload, CRC."""
    if not 0 <= command <= 0xFF:
        raise ValueError(f"`command` must be a byte, got {command!r}")
    body = PREAMBLE + struct.pack("<BH", command, len(payload)) + payload
    return body + struct.pack("<H", crc16(body))


@dataclass(frozen=True)
class Frame:
    """One decoded frame: command id and payload (the CRC already checked)."""

    command: int
    payload: bytes

    @property
    def status(self) -> int:
        """The response's status code (responses only)."""
        if len(self.payload) < 2:
            raise FrameError(f"{command_name(self.command)}: response without a status")
        return int(struct.unpack_from("<H", self.payload)[0])

    @property
    def data(self) -> bytes:
        """The response's payload after its status."""
        return self.payload[2:]


class FrameDecoder:
    """Incremental decoder: ``feed(bytes)`` returns what the bytes completed, in order.

    Each item is a :class:`Frame` or a :class:`FrameError` (a CRC mismatch or an absurd
    length, naming the command and the bytes); after an error the decoder drops that
    frame's first byte and resynchronises on the next preamble. Bytes before a preamble
    are skipped and counted in ``skipped_bytes``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.skipped_bytes = 0

    @property
    def pending(self) -> bytes:
        """Bytes of an incomplete frame waiting for the rest."""
        return bytes(self._buf)

    def feed(self, data: bytes) -> list[Frame | FrameError]:
        self._buf += data
        out: list[Frame | FrameError] = []
        while True:
            start = self._buf.find(PREAMBLE)
            if start < 0:
                keep = 2 if self._buf.endswith(b"\xaa\xaa") else int(self._buf.endswith(b"\xaa"))
                self.skipped_bytes += len(self._buf) - keep
                del self._buf[: len(self._buf) - keep]
                return out
            if start:
                self.skipped_bytes += start
                del self._buf[:start]
            if len(self._buf) < HEADER_SIZE:
                return out
            command, length = struct.unpack_from("<BH", self._buf, 3)
            if length > MAX_PAYLOAD:
                del self._buf[:1]
                out.append(
                    FrameError(
                        f"{command_name(command)}: payload length {length} over {MAX_PAYLOAD}"
                        " (corrupt header)",
                        command,
                    )
                )
                continue
            end = HEADER_SIZE + length + 2
            if len(self._buf) < end:
                return out
            raw = bytes(self._buf[:end])
            if crc16(raw) != 0:
                del self._buf[:1]
                out.append(
                    FrameError(
                        f"{command_name(command)}: CRC mismatch in frame {raw.hex(' ')}"
                        f" (its CRC should be {crc16(raw[:-2]):04x})",
                        command,
                    )
                )
                continue
            del self._buf[:end]
            out.append(Frame(command, raw[HEADER_SIZE:-2]))


def response(command: int, status: int, data: bytes = b"") -> bytes:
    """A response frame: the status, then ``data``."""
    return encode_frame(command, struct.pack("<H", status) + data)


def f32(*values: float) -> bytes:
    """Little-endian IEEE-754 singles."""
    return struct.pack(f"<{len(values)}f", *values)


def read_f32(data: bytes, command: int) -> float:
    """The single float a value query returns; a short payload is a :class:`FrameError`."""
    if len(data) < 4:
        raise FrameError(f"{command_name(command)}: expected a float, got {data.hex(' ')!r}")
    return float(struct.unpack_from("<f", data)[0])


def query_payload(period_ms: int = 0) -> bytes:
    """Payload of a value query: auto-update every ``period_ms`` (0: answer once)."""
    if not 0 <= period_ms <= 0xFFFF:
        raise ValueError(f"`period_ms` must be in 0..65535, got {period_ms!r}")
    return struct.pack("<BH", AUTO_UPDATE if period_ms else 0, period_ms)


def move_payload(width_mm: float, speed_mm_per_s: float, *, stop_on_block: bool = True) -> bytes:
    """Payload of MOVE: flags (bit 1: stop on block), width, speed."""
    return struct.pack("<B", 0x02 if stop_on_block else 0x00) + f32(width_mm, speed_mm_per_s)


# The WSG 50's published limits: stroke, finger speed, grip force.
MAX_WIDTH_M = 0.110
MAX_SPEED_M_PER_S = 0.420
MAX_FORCE_N = 80.0
COMMANDS = ("move", "grasp", "release", "stop", "home")


def command_refusal(command: str, *, width_m: float, speed_m_per_s: float, force_n: float) -> str:
    """Why the WSG 50 would refuse a ``GripperCommand`` (field and value), or ``""``."""
    if command not in COMMANDS:
        return f"unknown command {command!r}; valid: {', '.join(COMMANDS)}"
    if command in ("stop", "home"):
        return ""
    if not 0.0 <= width_m <= MAX_WIDTH_M:
        return f"{command}: `width_m` must be in 0..{MAX_WIDTH_M} m, got {width_m!r}"
    if not 0.0 < speed_m_per_s <= MAX_SPEED_M_PER_S:
        return (
            f"{command}: `speed_m_per_s` must be in (0, {MAX_SPEED_M_PER_S}], got {speed_m_per_s!r}"
        )
    if not 0.0 < force_n <= MAX_FORCE_N:
        return f"{command}: `force_n` must be in (0, {MAX_FORCE_N}] N, got {force_n!r}"
    return ""
