"""Where a frame's CPU goes: ``bench.transport``'s runtime and raw paths step by step, in one process.

The two-process figures of ``bench.transport`` say how much more CPU a frame costs through
the runtime than through bare pyzmq, not where; on a shared machine they also move by
tens of percent between runs. Here each step of one frame's way runs in this process on
the same frames (``ToFImage`` of 172 x 224 depth and IR, the raw pair's
``[topic, stamp/seq + frame id, depth, ir]``), over a real ipc PUB/SUB pair, and is
timed by this thread's CPU clock (``time.thread_time_ns``: time spent waiting for the
machine does not count, so another engineer's load disturbs it far less).

Source side, per frame:

``message``   build the ``ToFImage`` as ``bench.image_source`` does; raw: pack its header
``encode``    ``messages.codec.encode``; raw: nothing (its header is the message)
``finite``    the finite check at publish (``Message.nonfinite_fields``); raw: none
``send``      ``runtime.zmqio.send_parts`` of the 5 parts; raw: ``send_multipart`` of 4
``publish``   all of it as the node does it: ``ImageSource._publish`` of one frame through
              ``ZmqIO.publish`` (checks, seq, encode, counts, send, finite check)

Sink side, per frame (after ``poll`` says a frame waits, as both sinks ask):

``receive``   ``runtime.zmqio.recv_parts``; raw: ``recv_multipart(copy=False)``
``decode``    ``messages.codec.decode`` (checked, typed); raw: unpack the header, wrap
              both buffers with ``np.frombuffer``
``deliver``   the node runner's whole path for a window of queued frames
              (``Runner._service``: receive, decode, count, hand to ``ImageSink``, an
              ack every 8th frame); raw: its sink loop's (receive, unpack, record, ack)

Rows: medians over repeats of the CPU per frame of a window of ``window`` frames
(runtime and raw alternating within each repeat), ``extra_us`` the difference and
``vs_raw`` the ratio (empty where raw does nothing). In one warm process every step
is cheaper than between two processes sharing two cores (cold caches, the other
process and the I/O threads in between): read the differences, not the totals.

    python -m bench.transport_steps [--quick] [--json]
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from bench.common import Row, main, median
from bench.nodes import THROUGHPUT, ImageSink, ImageSource, SinkRecord, bench_images
from bench.transport_bare import ACK, COLS, RAW_HEADER, ROWS, TOPIC, _raw_frames
from messages import ToFImage, decode, encode
from runtime.node import Node
from runtime.registry import class_path
from runtime.runner import Runner
from runtime.zmqio import Input, Source, recv_parts, send_parts

SOURCE_STEPS = ("message", "encode", "finite", "send", "publish")
SINK_STEPS = ("receive", "decode", "deliver")
WAIT_MS = 10_000  # for a frame sent in this process: it arrives unless something is broken


@dataclass(frozen=True)
class StepSizes:
    window: int  # frames per timed batch (bench.transport's window)
    batches: int  # batches per repeat
    repeats: int


QUICK = StepSizes(window=32, batches=3, repeats=3)
FULL = StepSizes(window=32, batches=30, repeats=9)


def _cpu_us(fn: Callable[[], Any], frames: int) -> float:
    """This thread's CPU in microseconds per frame while ``fn`` handles ``frames``."""
    start = time.thread_time_ns()
    fn()
    return (time.thread_time_ns() - start) / 1e3 / frames


class Bench:
    """Both paths' sockets and nodes in this process, and one timing per step and path."""

    def __init__(self, workdir: str, window: int) -> None:
        self.window = window
        self.depth_m, self.ir = bench_images(ROWS, COLS)
        self.source = self._runner(ImageSource, "source", workdir, {"image": TOPIC.decode()})
        self.sink = self._runner(ImageSink, "sink", workdir, {"ack": "sink/ack"})
        self.ctx = self.sink.ctx
        # The runtime's frames come from the source node's XPUB; raw's from a bare PUB.
        self.raw_pub = self.ctx.socket(zmq.PUB)
        self.raw_pub.bind(f"ipc://{workdir}/raw")
        self.raw_acks = self.ctx.socket(zmq.PUB)  # no reader: as the sink node's acks here
        self.raw_acks.bind(f"ipc://{workdir}/raw-acks")
        self.sub = self._sub(self.source.io.endpoint)
        self.raw_sub = self._sub(f"ipc://{workdir}/raw")
        self.input = Input("image", TOPIC.decode(), "queue", ToFImage)
        self.sink.io.inputs.append(self.input)
        self.feed = Source(self.sub, {TOPIC: [self.input]})
        self.record = SinkRecord(8)
        self._await_subscription()

    @staticmethod
    def _runner(cls: type[Node], name: str, workdir: str, outputs: dict[str, str]) -> Runner:
        runner = Runner(
            {
                "name": name,
                "class_path": class_path(cls),
                "params": {},
                "outputs": outputs,
                "inputs": [],
                "bind": f"ipc://{workdir}/{name}",
                "control": f"ipc://{workdir}/control",  # nothing is told: no listener
                "secret": "00" * 32,
            }
        )
        runner.node.setup()
        runner.io.timers.clear()  # nothing here runs the node's loop
        return runner

    def _sub(self, endpoint: str) -> zmq.Socket[Any]:
        sock = self.ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.RCVHWM, 0)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(endpoint)
        sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
        return sock

    def _await_subscription(self) -> None:
        """Probe both publishers until their subscriber hears them (a SUB joins late)."""
        for pub, sub in ((self.source.io.pub, self.sub), (self.raw_pub, self.raw_sub)):
            while not sub.poll(5):
                pub.send_multipart([TOPIC + b"/probe"])
            while sub.poll(50):
                sub.recv_multipart()

    # -- the frames -----------------------------------------------------------------
    def message(self) -> ToFImage:
        """What ``ImageSource._publish`` builds for one frame."""
        node = self.source.node
        assert isinstance(node, ImageSource)
        return node.frame(THROUGHPUT)

    def raw_frames(self) -> list[Any]:
        return _raw_frames(THROUGHPUT, 0, self.depth_m, self.ir)

    # -- timed windows ----------------------------------------------------------------
    def source_step(self, step: str, raw: bool) -> float | None:
        n = self.window
        msg, frames = self.message(), encode(TOPIC.decode(), self.message())
        raw_frames = self.raw_frames()
        pub = self.raw_pub if raw else self.source.io.pub
        sub = self.raw_sub if raw else self.sub
        if step == "message":
            make: Callable[[], Any] = self.raw_frames if raw else self.message
            cpu = _cpu_us(lambda: [make() for _ in range(n)], n)
        elif step in ("encode", "finite") and raw:
            return None
        elif step == "encode":
            cpu = _cpu_us(lambda: [encode(TOPIC.decode(), msg) for _ in range(n)], n)
        elif step == "finite":
            cpu = _cpu_us(lambda: [msg.nonfinite_fields() for _ in range(n)], n)
        elif step == "send" and raw:
            cpu = _cpu_us(lambda: [pub.send_multipart(raw_frames, copy=False) for _ in range(n)], n)
        elif step == "send":
            cpu = _cpu_us(lambda: [send_parts(pub, frames) for _ in range(n)], n)
        elif raw:  # publish: what the raw source does per frame
            cpu = _cpu_us(
                lambda: [pub.send_multipart(self.raw_frames(), copy=False) for _ in range(n)], n
            )
        else:
            node = self.source.node
            assert isinstance(node, ImageSource)
            cpu = _cpu_us(lambda: [node._publish([THROUGHPUT]) for _ in range(n)], n)
        if step in ("send", "publish"):
            self._drain(sub, n)
        return cpu

    @staticmethod
    def _drain(sub: zmq.Socket[Any], n: int) -> None:
        for _ in range(n):
            if not sub.poll(WAIT_MS):
                raise RuntimeError("a frame sent in this process did not arrive")
            sub.recv_multipart(copy=False)

    def _queue(self, raw: bool) -> None:
        """Send a window of frames to one path's SUB and let it arrive (untimed)."""
        for _ in range(self.window):
            if raw:
                self.raw_pub.send_multipart(self.raw_frames(), copy=False)
            else:
                send_parts(self.source.io.pub, encode(TOPIC.decode(), self.message()))
        # The I/O thread moves a window (7 MB) in a few milliseconds; a frame not in yet
        # is waited for by the timed step's poll, as a sink waits, without using the CPU.
        time.sleep(0.02)

    def sink_step(self, step: str, raw: bool) -> float:
        n = self.window
        self._queue(raw)
        sub = self.raw_sub if raw else self.sub
        if step == "receive":
            recv: Callable[[], Any] = (
                (lambda: sub.recv_multipart(copy=False)) if raw else (lambda: recv_parts(sub))
            )
            return _cpu_us(lambda: [sub.poll(WAIT_MS) and recv() for _ in range(n)], n)
        if step == "decode":
            windows = [sub.poll(WAIT_MS) and sub.recv_multipart(copy=False) for _ in range(n)]
            read = self._raw_read if raw else (lambda f: decode(f, expect=ToFImage))
            return _cpu_us(lambda: [read(f) for f in windows], n)
        if raw:
            return _cpu_us(lambda: self._raw_deliver(n), n)
        target = self.input.counters.received + n
        return _cpu_us(lambda: self._deliver_until(target), n)

    def _deliver_until(self, target: int) -> None:
        while self.input.counters.received < target:
            if not self.sub.poll(WAIT_MS):
                raise RuntimeError("a frame sent in this process did not arrive")
            self.sink._service(self.feed)

    @staticmethod
    def _raw_read(frames: list[Any]) -> tuple[int, int, str]:
        """What the raw sink does with a frame's parts (bench.transport_bare)."""
        header = frames[1].buffer
        stamp_nanos, seq = RAW_HEADER.unpack_from(header)
        frame_id = bytes(header[RAW_HEADER.size :]).decode()
        np.frombuffer(frames[2].buffer, np.float32).reshape(ROWS, COLS)
        np.frombuffer(frames[3].buffer, np.uint16).reshape(ROWS, COLS)
        return stamp_nanos, seq, frame_id

    def _raw_deliver(self, n: int) -> None:
        for _ in range(n):
            self.raw_sub.poll(WAIT_MS)
            stamp_nanos, seq, frame_id = self._raw_read(self.raw_sub.recv_multipart(copy=False))
            if self.record.take(stamp_nanos, seq, frame_id):
                self.raw_acks.send(ACK.pack(seq + 1))

    def close(self) -> None:
        for sock in (self.raw_pub, self.raw_acks, self.sub, self.raw_sub):
            sock.close(linger=0)
        for runner in (self.source, self.sink):
            self.close_runner(runner)

    @staticmethod
    def close_runner(runner: Runner) -> None:
        """Close what :meth:`_runner` opened."""
        runner.io.pub.close(linger=0)
        runner.io.control.close(linger=0)
        runner.ctx.term()


@contextmanager
def _bench(window: int) -> Iterator[Bench]:
    with tempfile.TemporaryDirectory(prefix="bench-steps-") as tmp:
        bench = Bench(tmp, window)
        try:
            yield bench
        finally:
            bench.close()


def run(quick: bool, sizes: StepSizes | None = None) -> list[Row]:
    sizes = sizes or (QUICK if quick else FULL)
    steps = [("source", s) for s in SOURCE_STEPS] + [("sink", s) for s in SINK_STEPS]
    cpu: dict[tuple[str, str, bool], list[float]] = {}
    with _bench(sizes.window) as bench:
        for repeat in range(sizes.repeats):
            for side, step in steps:
                for raw in (False, True) if repeat % 2 == 0 else (True, False):
                    # One window untimed first: the previous step left other data in the caches.
                    for batch in range(-1, sizes.batches):
                        if side == "source":
                            got = bench.source_step(step, raw)
                        else:
                            got = bench.sink_step(step, raw)
                        if got is not None and batch >= 0:
                            cpu.setdefault((side, step, raw), []).append(got)
    rows: list[Row] = []
    for side, step in steps:
        mine = median(cpu[(side, step, False)])
        theirs = cpu.get((side, step, True))
        row: Row = {"side": side, "step": step, "runtime_us": mine}
        if theirs:
            row["raw_us"] = median(theirs)
            row["extra_us"] = mine - row["raw_us"]
            row["vs_raw"] = mine / row["raw_us"]
        else:
            row["extra_us"] = mine
        row.update(window=sizes.window, windows=sizes.batches * sizes.repeats)
        rows.append(row)
    return rows


COLUMNS = ["side", "step", "runtime_us", "raw_us", "extra_us", "vs_raw", "window", "windows"]

if __name__ == "__main__":
    main("transport_steps", run, columns=COLUMNS)
