"""What the source's publish path costs between two processes, step against step in one run.

``bench.transport`` runs each implementation in its own pair of processes, seconds apart;
on a shared machine the load moves between the two by more than a few microseconds a
frame. ``bench.transport_steps`` times each step in one warm process, where nothing else
competes for the caches. This bench sits between them: the source is this process,
publishing :class:`messages.ToFImage` frames through a real node IO
(:class:`runtime.zmqio.ZmqIO`, as ``bench.image_source`` does) over ipc to a sink process
that decodes each frame with ``messages.codec`` and acknowledges every 8th (the bare
``codec`` sink of ``bench.transport``), at most 32 frames in flight. The variants
alternate every ``block`` frames within the one run, so a change of the machine's load
hits each alike:

``publish``       ``ZmqIO.publish`` as a node calls it: type check, seq, encode, count,
                  send, the finite check
``no_finite``     the same path without the finite check (what the check costs here)
``finite_twice``  ``publish`` and one more finite check of the frame: what a second pass
                  over a depth image that the first has just read costs in this loop
``encode_twice``  ``publish`` with the frame encoded once more first (the copy thrown
                  away): what encode costs here
``finite_first``  the same steps as ``publish`` with the finite check before the send
                  rather than after it

Rows: the CPU per frame of this process's main thread (``main_us_per_frame``, from
``time.thread_time_ns``) and of the whole process (``process_us_per_frame``: ZeroMQ's
I/O thread and pyzmq's zero-copy collector too), medians over blocks, and each one's
paired difference to ``publish`` (the median over rounds of the block's figure minus the
``publish`` block's of the same round, ``_q1``/``_q3`` the middle half of them).

    python -m bench.transport_source [--quick] [--json]
"""

from __future__ import annotations

import multiprocessing as mp
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from bench.common import Row, main, median
from bench.nodes import LAST, THROUGHPUT, ImageSource
from bench.transport_bare import ACK, PROBE, TIMEOUT_MS, Sizes, _sink_process
from bench.transport_steps import Bench
from messages.codec import encode
from runtime.runner import Runner
from runtime.zmqio import send_parts

VARIANTS = ("publish", "no_finite", "finite_twice", "encode_twice", "finite_first")
TOPIC = "source/image"


@dataclass(frozen=True)
class SourceSizes:
    rounds: int  # each variant runs one block per round
    block: int  # frames per timed block
    window: int = 32  # frames in flight (bench.transport's)


QUICK = SourceSizes(rounds=3, block=64)
FULL = SourceSizes(rounds=30, block=256)


def _publishers(runner: Runner) -> dict[str, Callable[[str], None]]:
    """Each variant: publish one frame of ``frame_id`` through ``runner``'s IO."""
    node = runner.node
    assert isinstance(node, ImageSource)
    io = runner.io

    message = node.frame

    def publish(frame_id: str) -> None:
        io.publish("image", message(frame_id))

    def no_finite(frame_id: str) -> None:
        msg = message(frame_id)
        msg.header.seq = io.published[TOPIC]
        frames = encode(TOPIC, msg)
        io.published[TOPIC] += 1
        send_parts(io.pub, frames)

    def finite_twice(frame_id: str) -> None:
        msg = message(frame_id)
        io.publish("image", msg)
        msg.nonfinite_fields()

    def encode_twice(frame_id: str) -> None:
        msg = message(frame_id)
        encode(TOPIC, msg)
        io.publish("image", msg)

    def finite_first(frame_id: str) -> None:
        msg = message(frame_id)
        msg.header.seq = io.published[TOPIC]
        frames = encode(TOPIC, msg)
        io.published[TOPIC] += 1
        msg.nonfinite_fields()
        send_parts(io.pub, frames)

    return {
        "publish": publish,
        "no_finite": no_finite,
        "finite_twice": finite_twice,
        "encode_twice": encode_twice,
        "finite_first": finite_first,
    }


def run(quick: bool, sizes: SourceSizes | None = None) -> list[Row]:
    sizes = sizes or (QUICK if quick else FULL)
    order = [v for r in range(sizes.rounds) for v in (VARIANTS if r % 2 == 0 else VARIANTS[::-1])]
    main_us: dict[str, list[float]] = {v: [] for v in VARIANTS}
    process_us: dict[str, list[float]] = {v: [] for v in VARIANTS}
    sink_sizes = Sizes(latency_frames=1, throughput_frames=len(order) * sizes.block, repeats=1)
    with tempfile.TemporaryDirectory(prefix="bench-source-") as tmp:
        runner = Bench._runner(ImageSource, "source", tmp, {"image": TOPIC})
        io = runner.io
        acks = io.ctx.socket(zmq.PULL)
        acks.setsockopt(zmq.LINGER, 0)
        acks.bind(f"ipc://{tmp}/ack")
        spawn = mp.get_context("spawn")
        result, result_end = spawn.Pipe()
        sink = spawn.Process(
            target=_sink_process,
            args=(result_end, "codec", [io.endpoint, f"ipc://{tmp}/ack"], sink_sizes),
        )
        sink.start()
        try:
            while not acks.poll(5):  # a subscriber joins late: probe until it answers
                io.pub.send(PROBE)
            acks.recv()
            publishers = _publishers(runner)
            sent = acked = 0
            for k, variant in enumerate(order):
                publish = publishers[variant]
                cpu, process = time.thread_time_ns(), time.process_time_ns()
                for i in range(sizes.block):
                    while sent - acked >= sizes.window:
                        if not acks.poll(TIMEOUT_MS):
                            raise RuntimeError("the sink stopped acknowledging")
                        acked = max(acked, ACK.unpack(acks.recv())[0])
                    last = k == len(order) - 1 and i == sizes.block - 1
                    publish(THROUGHPUT + (LAST if last else ""))
                    sent += 1
                main_us[variant].append((time.thread_time_ns() - cpu) / 1e3 / sizes.block)
                process_us[variant].append((time.process_time_ns() - process) / 1e3 / sizes.block)
            if not result.poll(TIMEOUT_MS / 1000):
                raise RuntimeError("the sink sent no result")
            received = result.recv()
        finally:
            sink.join(timeout=5)
            if sink.is_alive():
                sink.kill()
            acks.close()
            Bench.close_runner(runner)
    return _rows(main_us, process_us, sizes, received)


def _rows(
    main_us: dict[str, list[float]],
    process_us: dict[str, list[float]],
    sizes: SourceSizes,
    received: dict[str, Any],
) -> list[Row]:
    rows: list[Row] = []
    for variant in VARIANTS:
        row: Row = {"variant": variant}
        for name, figures in (("main", main_us), ("process", process_us)):
            diffs = [
                mine - base for mine, base in zip(figures[variant], figures["publish"], strict=True)
            ]
            q1, q3 = np.percentile(diffs, [25, 75])
            row[f"{name}_us_per_frame"] = median(figures[variant])
            row[f"{name}_extra_us"] = median(diffs)
            row[f"{name}_extra_us_q1"] = float(q1)
            row[f"{name}_extra_us_q3"] = float(q3)
        row.update(block=sizes.block, rounds=sizes.rounds, sink_dropped=received["dropped"])
        rows.append(row)
    return rows


COLUMNS = [
    "variant",
    "main_us_per_frame",
    "main_extra_us",
    "main_extra_us_q1",
    "main_extra_us_q3",
    "process_us_per_frame",
    "process_extra_us",
    "block",
    "rounds",
    "sink_dropped",
]

if __name__ == "__main__":
    main("transport_source", run, columns=COLUMNS)
