"""Benchmark nodes: a ToF image source and sink that measure the transport between them.

Used by ``bench/transport.py`` through the real launcher: two node processes, one
edge of :class:`messages.ToFImage` (one message per frame: depth float32 + IR uint16,
``rows`` x ``cols``, one sensor) and an acknowledgement edge back
(:class:`messages.Tick`) that bounds the frames in flight. A run has two phases, told
apart by ``header.frame_id``:

``latency``     ``latency_frames`` frames at ``rate_hz``, each stamped (wall clock,
                nanoseconds) just before it is encoded and published; the sink records
                ``receive time - stamp`` once the frame is decoded and handed to it.
``throughput``  ``throughput_frames`` frames as fast as the acks allow: at most
                ``window`` frames published and not yet acknowledged.

The sink acknowledges every ``ack_every``-th frame and the last frame of each phase
with ``value`` = the publisher's count through that frame (``header.seq + 1``), so a
frame lost at a high-water mark does not stall the window. The source starts the
throughput phase once every latency frame is acknowledged, and asks the graph to stop
once every frame is. :class:`WindowPlan` and :class:`SinkRecord` hold that logic; the
raw pyzmq side of the benchmark uses the same two classes.

Ports:
    bench.image_source   inputs: ack (Tick)        outputs: image (ToFImage)
    bench.image_sink     inputs: image (ToFImage)  outputs: ack (Tick)

On a clean stop the sink writes :meth:`SinkRecord.result` and the source
:meth:`WindowPlan.result` to their ``out_path`` (JSON). Both include the process CPU
time (every thread: the node's, ZeroMQ's I/O thread, the heartbeat) spent over the
throughput phase, a figure that a loaded machine disturbs far less than wall time.
"""

from __future__ import annotations

import json
import os
import threading
import time
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from messages import Header, Tick, ToFImage
from runtime.node import Node
from runtime.registry import register

LATENCY = "latency"
WAIT = "wait"
THROUGHPUT = "throughput"
LAST = "/last"  # suffix of the frame_id of a phase's last frame


def bench_images(rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """A depth image (float32 metres, some NaN pixels) and an IR image (uint16) to send."""
    rng = np.random.default_rng(0)
    depth_m = rng.uniform(0.02, 0.12, (rows, cols)).astype(np.float32)
    depth_m[::17, ::13] = np.nan  # invalid pixels, as the camera reports them
    ir = rng.integers(0, 4096, (rows, cols), dtype=np.uint16)
    return depth_m, ir


THREAD_GROUPS = ("main", "zmq_io", "other")


def thread_cpu_nanos() -> dict[int, tuple[str, int]]:
    """Each thread of this process: its name and CPU time so far in nanoseconds (the first
    field of Linux's ``/proc/self/task/<tid>/schedstat``); empty where there is none."""
    out: dict[int, tuple[str, int]] = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                nanos = int(f.read().split()[0])
            with open(f"/proc/self/task/{tid}/comm") as f:
                name = f.read().strip()
        except (OSError, ValueError, IndexError):
            continue  # a thread that ended meanwhile
        out[int(tid)] = (name, nanos)
    return out


def thread_split(
    start: dict[int, tuple[str, int]], end: dict[int, tuple[str, int]], main: int
) -> dict[str, int]:
    """CPU nanoseconds between two :func:`thread_cpu_nanos` snapshots, summed per group:
    ``main`` (the thread ``main``, which runs the sending or receiving loop), ``zmq_io``
    (ZeroMQ's I/O threads) and ``other`` (pyzmq's zero-copy garbage collector, a node's
    heartbeat, ...)."""
    split = dict.fromkeys(THREAD_GROUPS, 0)
    for tid, (name, nanos) in end.items():
        group = "main" if tid == main else "zmq_io" if name.startswith("ZMQbg/IO") else "other"
        split[group] += nanos - start.get(tid, (name, 0))[1]
    return split


class WindowPlan:
    """Which frames a source sends when: the latency phase by timer, then by window.

    Every frame id it returns counts as sent; the caller must publish it.
    """

    def __init__(self, latency_frames: int, throughput_frames: int, window: int) -> None:
        self.latency_frames = latency_frames
        self.throughput_frames = throughput_frames
        self.window = window
        self.total = latency_frames + throughput_frames
        self.phase = LATENCY if latency_frames else THROUGHPUT
        self.sent = 0
        self.acked = 0  # the publisher's count through the newest acknowledged frame
        self.throughput_sent = 0
        # Process CPU time (every thread) from the first throughput frame to the last ack,
        # and each thread's (thread_split).
        self.cpu_start_nanos = 0
        self.cpu_end_nanos = 0
        self.threads_start: dict[int, tuple[str, int]] = {}
        self.threads_end: dict[int, tuple[str, int]] = {}
        self.loop_thread = 0  # the thread running the loop (the split's ``main``)

    @property
    def done(self) -> bool:
        """Every frame is sent and acknowledged."""
        return self.acked >= self.total

    def on_timer(self) -> list[str]:
        """Frame ids to send on a timer tick (one latency frame, or a window's worth)."""
        if self.phase == LATENCY:
            self.sent += 1
            if self.sent == self.latency_frames:
                self.phase = WAIT
                return [LATENCY + LAST]
            return [LATENCY]
        return self.fill()

    def fill(self) -> list[str]:
        """Throughput frame ids that fit in the window now (none outside that phase)."""
        ids: list[str] = []
        if self.phase != THROUGHPUT:
            return ids
        if not self.throughput_sent:
            self.threads_start = thread_cpu_nanos()
            self.loop_thread = threading.get_native_id()
            self.cpu_start_nanos = time.process_time_ns()
        while (
            self.sent - self.acked < self.window and self.throughput_sent < self.throughput_frames
        ):
            self.sent += 1
            self.throughput_sent += 1
            last = self.throughput_sent == self.throughput_frames
            ids.append(THROUGHPUT + (LAST if last else ""))
        return ids

    def on_ack(self, count: int) -> list[str]:
        """Take an acknowledgement (publisher's count through a frame); frame ids to send."""
        self.acked = max(self.acked, count)
        if self.phase == WAIT and self.acked >= self.sent:
            self.phase = THROUGHPUT
        if self.done and not self.cpu_end_nanos:
            self.cpu_end_nanos = time.process_time_ns()
            self.threads_end = thread_cpu_nanos()
        return self.fill()

    def result(self) -> dict[str, Any]:
        """JSON-able figures of the sending side."""
        return {
            "sent": self.sent,
            "acked": self.acked,
            "throughput_frames": self.throughput_sent,
            "throughput_cpu_nanos": self.cpu_end_nanos - self.cpu_start_nanos,
            "throughput_thread_cpu_nanos": thread_split(
                self.threads_start, self.threads_end, self.loop_thread
            ),
        }


class SinkRecord:
    """What a sink measures: latency per latency frame, receive times of the throughput phase."""

    def __init__(self, ack_every: int) -> None:
        self.ack_every = ack_every
        self.received = 0
        self.dropped = 0
        self.last_seq: int | None = None
        self.latency_nanos: list[int] = []
        self.throughput_frames = 0
        self.throughput_first_nanos = 0
        self.throughput_last_nanos = 0
        self.cpu_start_nanos = 0
        self.cpu_end_nanos = 0
        self.threads_start: dict[int, tuple[str, int]] = {}
        self.threads_end: dict[int, tuple[str, int]] = {}
        self.loop_thread = 0  # the thread running the loop (the split's ``main``)

    def take(self, stamp_nanos: int, seq: int, frame_id: str) -> bool:
        """Record one frame at its arrival; True when it is to be acknowledged."""
        now = time.time_ns()
        if frame_id.startswith(LATENCY):
            self.latency_nanos.append(now - stamp_nanos)
        else:
            mono = time.monotonic_ns()
            if not self.throughput_frames:
                self.throughput_first_nanos = mono
                self.threads_start = thread_cpu_nanos()
                self.loop_thread = threading.get_native_id()
                self.cpu_start_nanos = time.process_time_ns()
            elif frame_id.endswith(LAST):
                self.cpu_end_nanos = time.process_time_ns()
                self.threads_end = thread_cpu_nanos()
            self.throughput_last_nanos = mono
            self.throughput_frames += 1
        if self.last_seq is not None and seq > self.last_seq + 1:
            self.dropped += seq - self.last_seq - 1
        self.last_seq = seq
        self.received += 1
        return self.received % self.ack_every == 0 or frame_id.endswith(LAST)

    def finished(self, frame_id: str, throughput_frames: int) -> bool:
        """True after the last frame of the run (a loop without a graph stops on it)."""
        if throughput_frames:
            return frame_id == THROUGHPUT + LAST
        return frame_id == LATENCY + LAST

    def result(self) -> dict[str, Any]:
        """JSON-able measurements (nanoseconds; throughput times are monotonic)."""
        return {
            "received": self.received,
            "dropped": self.dropped,
            "latency_nanos": self.latency_nanos,
            "throughput_frames": self.throughput_frames,
            "throughput_receive_nanos": [self.throughput_first_nanos, self.throughput_last_nanos],
            "throughput_cpu_nanos": self.cpu_end_nanos - self.cpu_start_nanos,
            "throughput_thread_cpu_nanos": thread_split(
                self.threads_start, self.threads_end, self.loop_thread
            ),
        }


class ImageSourceParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rows: Annotated[int, Meta(ge=1)] = 172
    cols: Annotated[int, Meta(ge=1)] = 224
    latency_frames: Annotated[int, Meta(ge=0)] = 1000
    rate_hz: Annotated[float, Meta(gt=0)] = 1000.0
    throughput_frames: Annotated[int, Meta(ge=0)] = 2000
    window: Annotated[int, Meta(ge=1)] = 32
    out_path: str = ""


@register("bench.image_source")
class ImageSource(Node):
    """Publishes the latency phase at ``rate_hz``, then the throughput phase by window."""

    Params = ImageSourceParams
    inputs = {"ack": Tick}
    outputs = {"image": ToFImage}

    def setup(self) -> None:
        p = self.params
        self.depth_m, self.ir = bench_images(p.rows, p.cols)
        self.plan = WindowPlan(p.latency_frames, p.throughput_frames, p.window)
        self.stop_asked = False
        self.io.add_timer(1.0 / p.rate_hz, self._tick)

    def frame(self, frame_id: str) -> ToFImage:
        """The message of one frame, stamped now."""
        return ToFImage(
            header=Header(stamp_nanos=self.io.now_nanos(), frame_id=frame_id),
            sensor="left",
            depth_m=self.depth_m,
            ir=self.ir,
            fx_px=210.0,
            fy_px=210.0,
            cx_px=(self.params.cols - 1) / 2,
            cy_px=(self.params.rows - 1) / 2,
        )

    def _publish(self, frame_ids: list[str]) -> None:
        for frame_id in frame_ids:
            self.io.publish("image", self.frame(frame_id))

    def _tick(self) -> None:
        if not self.plan.done:
            self._publish(self.plan.on_timer())
        if self.plan.phase != LATENCY:
            # The timer paces the latency phase only; the rest goes by acknowledgement,
            # as the raw source's does: a node woken 1000 times a second for nothing
            # would pay for the wake-ups in the figures this source measures.
            self.io.cancel_timer(self._tick)

    def on_ack(self, msg: Tick) -> None:
        self._publish(self.plan.on_ack(int(msg.value)))
        if self.plan.done and not self.stop_asked:
            self.stop_asked = True
            self.io.request_stop(f"{self.plan.sent} frames sent and acknowledged")

    def teardown(self) -> None:
        if self.params.out_path:
            with open(self.params.out_path, "w") as f:
                json.dump(self.plan.result(), f)


class ImageSinkParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    out_path: str = ""
    ack_every: Annotated[int, Meta(ge=1)] = 8


@register("bench.image_sink")
class ImageSink(Node):
    """Records latency and receive times; acknowledges so the source can bound its window."""

    Params = ImageSinkParams
    inputs = {"image": ToFImage}
    outputs = {"ack": Tick}

    def setup(self) -> None:
        self.record = SinkRecord(self.params.ack_every)

    def on_image(self, msg: ToFImage) -> None:
        header = msg.header
        if self.record.take(header.stamp_nanos, header.seq, header.frame_id):
            self.io.publish("ack", Tick(header=Header(), value=float(header.seq + 1)))

    def teardown(self) -> None:
        result = self.record.result()
        self.io.log.info("received %d frames (%d dropped)", result["received"], result["dropped"])
        if self.params.out_path:
            with open(self.params.out_path, "w") as f:
                json.dump(result, f)
