"""The WSG 50 protocol byte for byte, the client against the emulator, and every failure.

Misbehaving grippers are small fake servers; each failure must surface as a clear error
within the client's timeout (asserted with generous margins), never a hang.
"""

from __future__ import annotations

import socket
import struct
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from devices.wsg50 import (
    Cmd,
    ConnectionLost,
    DeviceError,
    Frame,
    FrameDecoder,
    FrameError,
    GraspState,
    Status,
    StatusError,
    WSGTimeout,
    crc16,
    encode_frame,
    query_payload,
    response,
)
from devices.wsg50_client import WSG50Client, float_value
from tests.devices.wsg50_helpers import fake_gripper, recv_exactly, running_emulator, until

KNOWN = {
    "homing": (Cmd.HOMING, b"\x00", "aa aa aa 20 01 00 00 8f 83"),
    "stop": (Cmd.STOP, b"", "aa aa aa 22 00 00 0e 76"),
    "get opening": (Cmd.GET_OPENING, query_payload(0), "aa aa aa 43 03 00 00 00 00 b8 10"),
}


@pytest.mark.parametrize("name", KNOWN)
def test_known_frames_byte_for_byte(name: str) -> None:
    command, payload, expected = KNOWN[name]
    frame = encode_frame(command, payload)
    assert frame == bytes.fromhex(expected)
    assert crc16(frame) == 0  # the CRC over a whole frame is zero
    assert FrameDecoder().feed(frame) == [Frame(command, payload)]


@given(
    command=st.integers(0, 255),
    payload=st.binary(max_size=64),
    junk=st.binary(max_size=8).filter(lambda b: b"\xaa" not in b),
    cut=st.integers(1, 80),
)
def test_decoder_reassembles_frames_split_anywhere(
    command: int, payload: bytes, junk: bytes, cut: int
) -> None:
    stream = junk + encode_frame(command, payload) + encode_frame(0x43, b"\x01")
    decoder = FrameDecoder()
    out = []
    for i in range(0, len(stream), cut):
        out += decoder.feed(stream[i : i + cut])
    assert out == [Frame(command, payload), Frame(0x43, b"\x01")]
    assert decoder.skipped_bytes == len(junk)


def test_decoder_reports_a_bad_crc_and_keeps_the_next_frame() -> None:
    bad = bytearray(encode_frame(Cmd.STOP))
    bad[-1] ^= 0xFF
    out = FrameDecoder().feed(bytes(bad) + encode_frame(Cmd.HOMING, b"\x00"))
    assert isinstance(out[0], FrameError) and "CRC mismatch" in str(out[0])
    assert out[0].command == Cmd.STOP
    assert out[1] == Frame(Cmd.HOMING, b"\x00")


def _exchange(
    sock: socket.socket, command: int, payload: bytes, *, skipping: tuple[int, ...] = ()
) -> Frame:
    """Send one hand-built frame; read complete frames off the socket until its response
    (those of the commands in ``skipping``, a stream's, are checked and passed over)."""
    body = b"\xaa\xaa\xaa" + struct.pack("<BH", command, len(payload)) + payload
    sock.sendall(body + struct.pack("<H", crc16(body)))
    while True:
        header = recv_exactly(sock, 6)
        assert header[:3] == b"\xaa\xaa\xaa"
        (length,) = struct.unpack_from("<H", header, 4)
        rest = recv_exactly(sock, length + 2)
        assert crc16(header + rest) == 0, (header + rest).hex(" ")
        if header[3] not in skipping:
            assert header[3] == command
            return Frame(command, rest[:-2])


def _f(frame: Frame) -> float:
    return float(struct.unpack_from("<f", frame.data)[0])


def test_every_command_round_trip_on_the_wire() -> None:
    f32 = struct.Struct("<f").pack
    with running_emulator(part_width_m=0.05) as server:
        sock = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        with sock:
            # Value queries: status + float32 (opening mm, speed mm/s, force N) or one byte.
            assert _exchange(sock, 0x43, b"\x00\x00\x00").payload == b"\x00\x00" + f32(110.0)
            assert _exchange(sock, 0x44, b"\x00\x00\x00").payload == b"\x00\x00" + f32(0.0)
            assert _exchange(sock, 0x45, b"\x00\x00\x00").payload == b"\x00\x00" + f32(0.0)
            assert _exchange(sock, 0x41, b"\x00\x00\x00").payload == b"\x00\x00\x00"
            assert _exchange(sock, 0x32, f32(20.0)).payload == b"\x00\x00"
            assert _exchange(sock, 0x33, b"").payload == b"\x00\x00" + f32(20.0)
            # Motion: E_CMD_PENDING (26) now, the final status when the jaws stop.
            assert _exchange(sock, 0x21, b"\x02" + f32(80.0) + f32(400.0)).payload == b"\x1a\x00"
            assert recv_exactly(sock, 10) == response(0x21, 0)
            assert _exchange(sock, 0x25, f32(50.0) + f32(200.0)).payload == b"\x1a\x00"
            assert recv_exactly(sock, 10) == response(0x25, 0)
            assert _exchange(sock, 0x41, b"\x00\x00\x00").payload == b"\x00\x00\x04"  # HOLDING
            assert _f(_exchange(sock, 0x45, b"\x00\x00\x00")) == pytest.approx(20.0, abs=0.5)
            assert _exchange(sock, 0x26, f32(100.0) + f32(400.0)).payload == b"\x1a\x00"
            assert recv_exactly(sock, 10) == response(0x26, 0)
            assert _f(_exchange(sock, 0x43, b"\x00\x00\x00")) == pytest.approx(100.0)
            assert _exchange(sock, 0x20, b"\x00").payload == b"\x1a\x00"
            assert recv_exactly(sock, 10) == response(0x20, 0)
            assert _exchange(sock, 0x22, b"").payload == b"\x00\x00"
            assert _exchange(sock, 0x23, b"").payload == b"\x00\x00"
            assert _exchange(sock, 0x21, b"\x02" + f32(80.0) + f32(400.0)).payload == b"\x10\x00"
            assert _exchange(sock, 0x24, b"ack").payload == b"\x00\x00"
            # Errors: unknown command, wrong payload size, out of range.
            assert _exchange(sock, 0x99, b"").payload == b"\x0e\x00"  # E_CMD_UNKNOWN
            assert _exchange(sock, 0x25, b"\x00").payload == b"\x0f\x00"  # E_CMD_FORMAT_ERROR
            assert _exchange(sock, 0x32, f32(500.0)).payload == b"\x1c\x00"  # E_RANGE_ERROR
            # Streams: the auto-update option sends the opening every 20 ms.
            assert _exchange(sock, 0x43, b"\x01\x14\x00").status == 0
            first = recv_exactly(sock, 14)
            assert first == response(0x43, 0, f32(110.0))
            # The stream goes on meanwhile: on a busy machine more openings may come first.
            assert _exchange(sock, 0x07, b"", skipping=(0x43,)).payload == b"\x00\x00"


def test_a_frame_with_a_bad_crc_is_answered_checksum_error() -> None:
    with running_emulator() as server, socket.create_connection(("127.0.0.1", server.port)) as s:
        bad = bytearray(encode_frame(Cmd.GET_OPENING, query_payload(0)))
        bad[-2] ^= 0x01
        s.sendall(bytes(bad))
        assert recv_exactly(s, 10) == response(Cmd.GET_OPENING, Status.E_CHECKSUM_ERROR)


def test_client_drives_the_emulator() -> None:
    events: list[str] = []
    with running_emulator(part_width_m=0.05) as server:
        with WSG50Client("127.0.0.1", server.port, on_event=events.append) as client:
            client.stream(Cmd.GET_OPENING, 10)
            client.set_force_limit(15.0)
            assert client.force_limit_n() == pytest.approx(15.0)
            assert client.move(0.08, 0.4).wait(5) == Status.E_SUCCESS
            assert client.opening_m() == pytest.approx(0.08)
            assert client.grasp(0.05, 0.2).wait(5) == Status.E_SUCCESS
            assert client.grasp_state() == GraspState.HOLDING
            time.sleep(0.05)  # a few steps of holding still
            assert client.speed_m_per_s() == 0.0
            assert client.force_n() == pytest.approx(15.0, abs=0.5)
            # The next streamed opening: a 50 mm part, 15 N at 5 N/mm.
            assert client.opening_m() == pytest.approx(0.047, abs=5e-4)
            assert float_value(client.latest(Cmd.GET_OPENING), Cmd.GET_OPENING) is not None
            assert client.release(0.1, 0.4).wait(5) == Status.E_SUCCESS
            with pytest.raises(StatusError, match="E_AXIS_BLOCKED"):
                client.move(0.02, 0.1).wait(5)  # the part blocks the jaws
            motion = client.home()
            with pytest.raises(DeviceError, match="still running"):
                client.move(0.05, 0.1)
            client.stop()
            with pytest.raises(StatusError, match="E_CMD_ABORTED"):
                motion.wait(5)
            client.fast_stop()
            with pytest.raises(StatusError, match="E_ACCESS_DENIED"):
                client.move(0.05, 0.1)
            client.ack_fault()
            assert client.home().wait(5) == Status.E_SUCCESS
            with pytest.raises(StatusError, match="E_CMD_UNKNOWN"):
                client.request(0x99)
    assert events == []


def test_a_grasp_on_nothing_fails_no_part_found() -> None:
    with running_emulator(part_width_m=0.0) as server:
        with WSG50Client("127.0.0.1", server.port) as client:
            with pytest.raises(StatusError, match="E_CMD_FAILED"):
                client.grasp(0.05, 0.4).wait(5)
            assert client.grasp_state() == GraspState.NO_PART


def test_a_gripper_that_stops_answering_times_out() -> None:
    with fake_gripper(lambda conn: conn.recv(64)) as port:
        client = WSG50Client("127.0.0.1", port, timeout_secs=0.5, reconnect=False)
        client.connect()
        with pytest.raises(WSGTimeout, match=r"no answer to GET_OPENING \(0x43\) within 0.5 s"):
            client.opening_m()
        client.disconnect()


def test_a_truncated_frame_times_out_and_shows_the_bytes() -> None:
    half = response(Cmd.GET_OPENING, 0, struct.pack("<f", 1.0))[:7]
    with fake_gripper(lambda conn: (conn.recv(64), conn.sendall(half))) as port:
        client = WSG50Client("127.0.0.1", port, timeout_secs=0.5, reconnect=False)
        client.connect()
        with pytest.raises(WSGTimeout, match="7 bytes of a partial frame: aa aa aa 43"):
            client.opening_m()
        client.disconnect()


def test_a_bad_crc_from_the_gripper_is_an_error() -> None:
    bad = bytearray(response(Cmd.GET_OPENING, 0, struct.pack("<f", 1.0)))
    bad[-1] ^= 0x55
    with fake_gripper(lambda conn: (conn.recv(64), conn.sendall(bytes(bad)))) as port:
        with WSG50Client("127.0.0.1", port, timeout_secs=2.0, reconnect=False) as client:
            with pytest.raises(FrameError, match="GET_OPENING .* CRC mismatch"):
                client.opening_m()  # at once: the timeout would raise WSGTimeout


def test_a_gripper_closing_mid_frame_is_a_lost_connection() -> None:
    half = response(Cmd.GET_OPENING, 0, struct.pack("<f", 1.0))[:9]
    events: list[str] = []
    with fake_gripper(lambda conn: (conn.recv(64), conn.sendall(half), conn.close())) as port:
        client = WSG50Client(
            "127.0.0.1", port, timeout_secs=2.0, reconnect=False, on_event=events.append
        )
        client.connect()
        with pytest.raises(ConnectionLost, match="closed by the gripper in the middle of a frame"):
            client.opening_m()  # at once: the timeout would raise WSGTimeout
        with pytest.raises(ConnectionLost, match="not connected"):
            client.stop()
        client.disconnect()
    assert any("connection lost" in e for e in events)


def test_no_gripper_at_the_address_fails_within_the_connect_timeout() -> None:
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]  # closed again below: nothing listens there
    client = WSG50Client("127.0.0.1", port, connect_timeout_secs=0.5)
    with pytest.raises(ConnectionLost, match=f"127.0.0.1:{port}: cannot connect within 0.5 s"):
        client.connect()


def test_a_dropped_connection_is_reported_and_reconnected_with_its_streams() -> None:
    events: list[str] = []
    with running_emulator() as first:
        port = first.port
        client = WSG50Client("127.0.0.1", port, backoff_secs=0.05, on_event=events.append)
        client.connect()
        client.stream(Cmd.GET_OPENING, 10)
    # The emulator is gone; a new one comes up on the same port a moment later.
    time.sleep(0.3)
    with pytest.raises(ConnectionLost):
        client.opening_m()
    with running_emulator(port=port) as second:
        assert until(lambda: client.reconnects > 0)
        assert client.reconnects == 1
        seen = client.latest(Cmd.GET_OPENING)
        assert until(lambda: client.latest(Cmd.GET_OPENING) != seen)  # the stream came back
        assert client.opening_m() == pytest.approx(0.11)
        assert second.frames_received >= 1  # the restored stream
        client.disconnect()
    assert any("connection lost: closed by the gripper" in e for e in events), events
    assert any("reconnected after" in e for e in events), events
