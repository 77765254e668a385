"""The bare pyzmq pair of ``bench.transport`` (and ``bench.transport_netns``): two processes
that send the benchmark's frames without the runtime, and the figures every row shares.

``raw`` sends the pixel buffers as ``[topic, 16-byte stamp/seq + frame id, depth, ir]``
with pyzmq's multipart helpers; ``raw_parts`` the same through the runtime's part loops;
``codec`` encodes and decodes with ``messages.codec``. Both sides run the protocol of
:class:`bench.nodes.WindowPlan` and :class:`bench.nodes.SinkRecord`; with a
:class:`bench.netns.Net` each side runs in its own network namespace (CURVE if it has keys).
"""

from __future__ import annotations

import multiprocessing as mp
import struct
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from bench.common import Row, median, percentile
from bench.netns import SUBNET, Net, enter
from bench.nodes import LATENCY, SinkRecord, WindowPlan, bench_images
from messages import Header, ToFImage, decode, encode
from runtime.security import Guard, connect_to, serve
from runtime.zmqio import recv_parts, send_parts

ROWS, COLS = 172, 224
NETNS = ("netns_tcp", "netns_curve")  # between namespaces: bench.transport_netns
TOPIC = b"source/image"
PROBE = b"source/probe"
ACK = struct.Struct("<q")
RAW_HEADER = struct.Struct("<qq")  # stamp_nanos, seq; the frame id follows as UTF-8
TIMEOUT_MS = 20_000


@dataclass(frozen=True, kw_only=True)
class Sizes:
    latency_frames: int
    throughput_frames: int
    repeats: int
    rate_hz: float = 1000.0
    window: int = 32
    ack_every: int = 8
    hwm: int = 1000

    def __post_init__(self) -> None:
        for name in ("latency_frames", "throughput_frames", "repeats", "window", "ack_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.window >= self.hwm:
            raise ValueError(f"window must be < hwm ({self.hwm}), got {self.window}")


QUICK = Sizes(latency_frames=300, throughput_frames=1000, repeats=1)
# Many short repeats rather than a few long ones: each ratio to raw is paired within a
# repeat, and the median of 9 pairs moves less under load than that of 5 (about the
# same time in all).
FULL = Sizes(latency_frames=500, throughput_frames=3000, repeats=9)


@dataclass
class Measured:
    frames_per_sec: float
    latency_ms_median: float
    latency_ms_p99: float
    source_cpu_us_per_frame: float
    sink_cpu_us_per_frame: float
    drops: int
    # Each side's CPU per frame by thread (bench.nodes.thread_split): the loop's own
    # thread, ZeroMQ's I/O thread, the rest (pyzmq's zero-copy collector, a heartbeat).
    threads_us_per_frame: dict[str, float] = field(default_factory=dict)


def _summarise(sink: dict[str, Any], source: dict[str, Any]) -> Measured:
    """Figures of one run from the sink's :class:`SinkRecord` and source's :class:`WindowPlan`."""
    latencies_ms = np.asarray(sink["latency_nanos"], dtype=float) / 1e6
    first, last = sink["throughput_receive_nanos"]
    frames = sink["throughput_frames"]
    if frames < 2 or last <= first or not len(latencies_ms):
        raise RuntimeError(f"the sink measured too little: {frames} throughput frames")
    if source["acked"] < source["sent"]:
        raise RuntimeError(f"only {source['acked']} of {source['sent']} frames acknowledged")
    return Measured(
        frames_per_sec=(frames - 1) / ((last - first) / 1e9),
        latency_ms_median=median(latencies_ms.tolist()),
        latency_ms_p99=percentile(latencies_ms.tolist(), 99),
        source_cpu_us_per_frame=source["throughput_cpu_nanos"] / 1e3 / source["throughput_frames"],
        sink_cpu_us_per_frame=sink["throughput_cpu_nanos"] / 1e3 / frames,
        drops=int(sink["dropped"]),
        threads_us_per_frame={
            f"{side}_{group}_us_per_frame": nanos / 1e3 / count
            for side, record, count in (
                ("source", source, source["throughput_frames"]),
                ("sink", sink, frames),
            )
            for group, nanos in record.get("throughput_thread_cpu_nanos", {}).items()
        },
    )


def _endpoint(transport: str, workdir: Path, name: str) -> str:
    if transport in NETNS:
        return f"tcp://{SUBNET}.1:*"  # the source's namespace
    return f"ipc://{workdir}/{name}" if transport == "ipc" else "tcp://127.0.0.1:*"


def _raw_frames(frame_id: str, seq: int, depth_m: np.ndarray, ir: np.ndarray) -> list[Any]:
    header = RAW_HEADER.pack(time.time_ns(), seq) + frame_id.encode()
    return [TOPIC, header, depth_m, ir]


def _codec_frames(frame_id: str, seq: int, depth_m: np.ndarray, ir: np.ndarray) -> list[Any]:
    rows, cols = depth_m.shape
    msg = ToFImage(
        header=Header(stamp_nanos=time.time_ns(), seq=seq, frame_id=frame_id),
        sensor="left",
        depth_m=depth_m,
        ir=ir,
        fx_px=210.0,
        fy_px=210.0,
        cx_px=(cols - 1) / 2,
        cy_px=(rows - 1) / 2,
    )
    return encode(TOPIC.decode(), msg)


def _source_process(
    conn: Connection, impl: str, transport: str, sizes: Sizes, workdir: str, net: Net | None = None
) -> None:
    """The sending process: PUB for frames, PULL for acks; paced, then windowed.

    With ``net``: in the first namespace, both sockets CURVE servers if it has keys."""
    if net is not None:
        enter(net.spaces[0])
    ctx: zmq.Context[Any] = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.SNDHWM, sizes.hwm)
    pub.setsockopt(zmq.LINGER, 1000)
    acks = ctx.socket(zmq.PULL)
    acks.setsockopt(zmq.LINGER, 0)
    guard = None
    if net is not None and net.keys is not None:
        server, client = net.keys
        guard = Guard(ctx, {client.public: "sink"}, print)
        for sock in (pub, acks):
            serve(sock, server)
        guard.start()
    pub.bind(_endpoint(transport, Path(workdir), "data"))
    acks.bind(_endpoint(transport, Path(workdir), "ack"))
    conn.send(
        [pub.getsockopt(zmq.LAST_ENDPOINT).decode(), acks.getsockopt(zmq.LAST_ENDPOINT).decode()]
    )
    depth_m, ir = bench_images(ROWS, COLS)
    make = _codec_frames if impl == "codec" else _raw_frames
    parts = impl == "raw_parts"
    plan = WindowPlan(sizes.latency_frames, sizes.throughput_frames, sizes.window)
    seq = 0

    def send(frame_ids: list[str]) -> None:
        nonlocal seq
        for frame_id in frame_ids:
            frames = make(frame_id, seq, depth_m, ir)
            if parts:
                send_parts(pub, frames)
            else:
                pub.send_multipart(frames, copy=False)
            seq += 1

    # A subscriber that connects late misses messages: probe until the sink answers.
    while not acks.poll(5):
        pub.send(PROBE)
    acks.recv()
    period = int(1e9 / sizes.rate_hz)
    due = time.monotonic_ns() + period
    while plan.phase == LATENCY:
        left = due - time.monotonic_ns()
        if left > 0:
            time.sleep(left / 1e9)
        send(plan.on_timer())
        # Skip missed periods rather than bursting, as the runtime's timers do.
        due = max(due + period, time.monotonic_ns())
    send(plan.fill())
    while not plan.done:
        if not acks.poll(TIMEOUT_MS):
            break
        send(plan.on_ack(ACK.unpack(acks.recv())[0]))
    conn.send(plan.result())
    pub.close()
    acks.close()
    if guard is not None:
        guard.close()
    ctx.term()


def _sink_process(
    conn: Connection, impl: str, endpoints: list[str], sizes: Sizes, net: Net | None = None
) -> None:
    """The receiving process: SUB for frames, PUSH for acks; sends its record back.

    With ``net``: in the second namespace, both sockets CURVE clients if it has keys."""
    if net is not None:
        enter(net.spaces[1])
    ctx: zmq.Context[Any] = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, sizes.hwm)
    sub.setsockopt(zmq.LINGER, 0)
    acks = ctx.socket(zmq.PUSH)
    if net is not None and net.keys is not None:
        server, client = net.keys
        for sock in (sub, acks):
            connect_to(sock, client, server.public)
    sub.connect(endpoints[0])
    sub.setsockopt(zmq.SUBSCRIBE, b"source/")
    acks.setsockopt(zmq.LINGER, 1000)
    acks.connect(endpoints[1])
    record = SinkRecord(sizes.ack_every)
    ready = False
    while sub.poll(TIMEOUT_MS):
        frames = recv_parts(sub) if impl == "raw_parts" else sub.recv_multipart(copy=False)
        assert frames is not None  # poll said a message waits
        if frames[0].bytes == PROBE:
            if not ready:
                acks.send(b"ready")
                ready = True
            continue
        if impl == "codec":
            _, msg = decode(frames, expect=ToFImage)
            stamp_nanos, seq, frame_id = msg.header.stamp_nanos, msg.header.seq, msg.header.frame_id
        else:
            header = frames[1].buffer
            stamp_nanos, seq = RAW_HEADER.unpack_from(header)
            frame_id = bytes(header[RAW_HEADER.size :]).decode()
            # What a receiver holds: the two images as arrays on the received buffers.
            np.frombuffer(frames[2].buffer, np.float32).reshape(ROWS, COLS)
            np.frombuffer(frames[3].buffer, np.uint16).reshape(ROWS, COLS)
        if record.take(stamp_nanos, seq, frame_id):
            acks.send(ACK.pack(seq + 1))
        if record.finished(frame_id, sizes.throughput_frames):
            break
    conn.send(record.result())
    sub.close()
    acks.close()
    ctx.term()


def run_bare(
    impl: str, transport: str, sizes: Sizes, workdir: Path, net: Net | None = None
) -> Measured:
    """Run the ``raw`` or ``codec`` pair of processes and read what the sink measured."""
    spawn = mp.get_context("spawn")
    source_end, source_conn = spawn.Pipe()
    sink_end, sink_conn = spawn.Pipe()
    source = spawn.Process(
        target=_source_process, args=(source_conn, impl, transport, sizes, str(workdir), net)
    )
    source.start()
    try:
        if not source_end.poll(TIMEOUT_MS / 1000):
            raise RuntimeError(f"{impl}/{transport}: the source process did not bind")
        endpoints = source_end.recv()
        sink = spawn.Process(target=_sink_process, args=(sink_conn, impl, endpoints, sizes, net))
        sink.start()
        try:
            if not sink_end.poll(2 * TIMEOUT_MS / 1000):
                raise RuntimeError(f"{impl}/{transport}: the sink process sent no result")
            result = sink_end.recv()
            if not source_end.poll(TIMEOUT_MS / 1000):
                raise RuntimeError(f"{impl}/{transport}: the source process sent no result")
            source_result = source_end.recv()
        finally:
            sink.join(timeout=5)
            if sink.is_alive():
                sink.kill()
    finally:
        source.join(timeout=5)
        if source.is_alive():
            source.kill()
    return _summarise(result, source_result)


def figures(m: Measured, sizes: Sizes, repeats: int) -> Row:
    """The measured figures of one row, and the sizes they were measured at."""
    return {
        "frames_per_sec": m.frames_per_sec,
        "latency_ms_median": m.latency_ms_median,
        "latency_ms_p99": m.latency_ms_p99,
        "megabytes_per_sec": m.frames_per_sec * frame_bytes() / 1e6,
        "source_cpu_us_per_frame": m.source_cpu_us_per_frame,
        "sink_cpu_us_per_frame": m.sink_cpu_us_per_frame,
        "drops": m.drops,
        **m.threads_us_per_frame,
        "repeats": repeats,
        "latency_frames": sizes.latency_frames,
        "throughput_frames": sizes.throughput_frames,
        "rate_hz": sizes.rate_hz,
        "window": sizes.window,
    }


def medians(measured: list[Measured]) -> Measured:
    return Measured(
        frames_per_sec=median([m.frames_per_sec for m in measured]),
        latency_ms_median=median([m.latency_ms_median for m in measured]),
        latency_ms_p99=median([m.latency_ms_p99 for m in measured]),
        source_cpu_us_per_frame=median([m.source_cpu_us_per_frame for m in measured]),
        sink_cpu_us_per_frame=median([m.sink_cpu_us_per_frame for m in measured]),
        drops=sum(m.drops for m in measured),
        threads_us_per_frame={
            key: median([m.threads_us_per_frame[key] for m in measured])
            for key in measured[0].threads_us_per_frame
            if all(key in m.threads_us_per_frame for m in measured)
        },
    )


def frame_bytes() -> int:
    """Pixel bytes of one frame (depth float32 + IR uint16)."""
    return ROWS * COLS * (4 + 2)
