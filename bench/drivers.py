"""The device drivers against their emulators: command latency, state rate, pressure reads.

Rows, one process, everything on loopback:

* ``wsg50_rtt``: microseconds from sending a WSG 50 command to its (immediate) answer,
  through ``devices.wsg50_client`` against ``sim.wsg50_server`` (emulator stepping at
  200 Hz in a thread), median and 90th percentile of ``calls`` calls, for a value query,
  a parameter write and a motion start (the ``E_CMD_PENDING`` answer); ``vs_raw`` divides
  the median by that of the same frame sent and read back on a bare socket, side by
  side, so the client's own cost is the ratio.
* ``wsg50_stream``: the opening streamed with the auto-update option at a requested
  rate: frames received per second over ``secs`` and the 90th percentile of the gap
  between frames.
* ``pressure_read``: ``devices.abp`` readings through ``devices.mcp2221`` and pyusb,
  against ``sim.mcp2221_emulator`` at the USB transfer level: reads per second and
  microseconds per read (three 64-byte report exchanges each). This is pyusb's and our
  cost alone: a real MCP2221A answers each report on a 1 ms interrupt frame, so a real
  read takes at least ~3 ms.

    python -m bench.drivers [--quick] [--json]
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

from bench.common import Row, main, median, percentile
from devices.abp import PSI_PA, AbpSensor
from devices.mcp2221 import MCP2221
from devices.wsg50 import Cmd, FrameDecoder, encode_frame, f32, move_payload, query_payload
from devices.wsg50_client import WSG50Client
from sim.gripper import GripperDynamics
from sim.mcp2221_emulator import EmulatedBackend, EmulatedBridge, abp_bytes
from sim.scene import GripperSpec
from sim.wsg50_server import WSG50Server, spring_part, step_in_real_time

COLUMNS = [
    "case",
    "command",
    "calls",
    "us_median",
    "us_p90",
    "vs_raw",
    "requested_hz",
    "received_hz",
    "gap_ms_p90",
    "reads_per_s",
]


def _times_us(call: Callable[[], object], calls: int) -> list[float]:
    out = []
    for _ in range(calls):
        start = time.perf_counter()
        call()
        out.append((time.perf_counter() - start) * 1e6)
    return out


def _raw_exchange(sock: socket.socket, frame: bytes, until: int) -> None:
    """Send ``frame`` on a bare socket; read frames until one of command ``until`` arrives
    (a motion's end may come first)."""
    sock.sendall(frame)
    decoder = FrameDecoder()
    while True:
        for item in decoder.feed(sock.recv(4096)):
            if item.command == until:
                return


def _wsg50_rows(server: WSG50Server, calls: int, stream_secs: float) -> list[Row]:
    rows: list[Row] = []
    raw = socket.create_connection(("127.0.0.1", server.port), timeout=5.0)
    raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    with WSG50Client("127.0.0.1", server.port) as client:

        def move_then_stop() -> None:
            client.move(0.1, 0.4)
            client.stop()

        move = encode_frame(Cmd.MOVE, move_payload(100.0, 400.0))
        stop = encode_frame(Cmd.STOP)

        def raw_move_then_stop() -> None:
            _raw_exchange(raw, move, Cmd.MOVE)  # E_CMD_PENDING
            _raw_exchange(raw, stop, Cmd.STOP)  # after the motion's end

        query = encode_frame(Cmd.GET_OPENING, query_payload())
        limit = encode_frame(Cmd.SET_FORCE_LIMIT, f32(20.0))
        cases: list[tuple[str, Callable[[], object], Callable[[], object]]] = [
            ("GET_OPENING", client.opening_m, lambda: _raw_exchange(raw, query, Cmd.GET_OPENING)),
            (
                "SET_FORCE_LIMIT",
                lambda: client.set_force_limit(20.0),
                lambda: _raw_exchange(raw, limit, Cmd.SET_FORCE_LIMIT),
            ),
            ("MOVE+STOP", move_then_stop, raw_move_then_stop),
        ]
        for name, call, bare_call in cases:
            # Interleaved, so ours and the bare socket see the same load.
            ours: list[float] = []
            bare: list[float] = []
            for _ in range(calls):
                ours += _times_us(call, 1)
                bare += _times_us(bare_call, 1)
            rows.append(
                {
                    "case": "wsg50_rtt",
                    "command": name,
                    "calls": calls,
                    "us_median": median(ours),
                    "us_p90": percentile(ours, 90),
                    "vs_raw": median(ours) / median(bare),
                }
            )
        for hz in (50, 100, 200):
            client.stream(Cmd.GET_OPENING, round(1000 / hz))
            stamps: list[float] = []
            last = client.latest(Cmd.GET_OPENING)
            end = time.monotonic() + stream_secs
            while time.monotonic() < end:
                entry = client.latest(Cmd.GET_OPENING)
                if entry is not None and entry is not last:
                    stamps.append(entry[1])
                    last = entry
                time.sleep(0.0005)
            gaps = [(b - a) * 1e3 for a, b in zip(stamps, stamps[1:], strict=False)]
            rows.append(
                {
                    "case": "wsg50_stream",
                    "command": "GET_OPENING",
                    "requested_hz": float(hz),
                    "received_hz": (len(stamps) - 1) / (stamps[-1] - stamps[0]),
                    "gap_ms_p90": percentile(gaps, 90),
                }
            )
    raw.close()
    return rows


def _pressure_row(reads: int) -> Row:
    backend = EmulatedBackend(
        EmulatedBridge("BENCH", sensor_bytes=abp_bytes(1000.0, pmin_pa=0.0, pmax_pa=PSI_PA))
    )
    with MCP2221("BENCH", backend=backend) as bridge:
        sensor = AbpSensor(bridge)
        times = _times_us(sensor.read, reads)
    return {
        "case": "pressure_read",
        "command": "ABP via MCP2221A",
        "calls": reads,
        "us_median": median(times),
        "us_p90": percentile(times, 90),
        "reads_per_s": 1e6 / median(times),
    }


def run(quick: bool) -> list[Row]:
    calls, stream_secs, reads = (30, 0.3, 200) if quick else (500, 2.0, 5000)
    dynamics = GripperDynamics(GripperSpec(), speed_limited=True)
    server = WSG50Server(dynamics).start()
    stop = threading.Event()
    stepper = threading.Thread(
        target=step_in_real_time,
        args=(server, spring_part(0.0, 0.0)),
        kwargs={"period_secs": 0.005, "stop": stop},
        daemon=True,
    )
    stepper.start()
    try:
        rows = _wsg50_rows(server, calls, stream_secs)
    finally:
        stop.set()
        stepper.join(timeout=2)
        server.close()
    rows.append(_pressure_row(reads))
    return rows


if __name__ == "__main__":
    main("drivers", run, columns=COLUMNS)
