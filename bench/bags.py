"""Bags: recording and replay throughput of the two-camera depth + IR stream.

One frame is one :class:`messages.ToFImage` of one sensor: 172 x 224 depth (float32) and
IR (uint16), 231,168 bytes of pixels plus a ~150-byte header; the stream alternates the
left and right cameras. Rows (``mode``):

``record_bag``        :class:`runtime.bag.BagWriter` recording the encoded multipart frames
                      as received: header check, each message packed as one MessagePack
                      value (``messages.codec.pack_single``), per-topic counts, periodic
                      flush every 0.5 s, uncompressed;
``record_raw_mcap``   the plain ``mcap`` ``Writer`` writing the same bytes (header and
                      buffers joined) on two channels, same chunk size, no compression:
                      the floor our layer adds to. Both run in this process, alternating,
                      ``repeats`` times; ``vs_raw`` is the ratio of medians.
``record_bag_zstd`` / ``record_raw_mcap_zstd``  the same with zstd chunks (full run only).
``record_live``       a live graph: two ``bench.image_source`` nodes at 45 fps (the
                      camera's fastest mode) into two sinks, recorded with
                      ``launch(record=...)``; ``dropped`` counts what the bag lacks
                      (sequence gaps, runtime drops, frames never recorded).
``record_pipeline``   the default graph (``graph.yaml``: simulated world, both cameras,
                      pressure, gripper, grasp monitor, shear, contact patch, IPOPT pose,
                      supervisor) with its cameras at 45 fps, recorded with
                      ``launch(record=...)``: the camera frames in the bag, their rate, and
                      ``dropped`` = frames the world made that the bag lacks, plus gaps.
``read``              :class:`runtime.bag.BagReader` iterating the bag and unpacking each
                      message into its wire frames (views on the mapped file: what replay
                      publishes), no typed decode;
``read_raw_mcap``     a third party's read of the same bag: the plain ``mcap`` reader and
                      ``msgpack.unpackb`` on each message (``vs_raw`` as above).
``replay_fast`` / ``replay_lockstep``  the ``replay`` node publishing the bag as fast as
                      possible, or in lockstep, into a sink node reading both cameras,
                      under the real launcher; throughput is counted at the sink from its
                      first to its last frame. ``lockstep_cost_pct`` = how much slower
                      lockstep is than fast. The sink reads both topics from one publisher
                      (the replay), so lockstep pipelines them (``Graph.barrier_topics``).
                      ``_fanin`` rows route the right camera through a relay node: the sink
                      then merges two publishers and lockstep waits for the graph to be
                      idle before every frame (replay -> relay -> sink -> launcher ->
                      replay). ``_work10ms`` rows give the sink 10 ms of busy work per
                      frame (a perception stage's order of cost).

    python -m bench.bags [--quick] [--json] [--no-plot]
"""

from __future__ import annotations

import contextlib
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import msgspec
import yaml
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bench.common import Row, launcher_log, main, median, progress
from messages import Header, ToFImage, encode
from runtime.bag import BagReader, BagWriter
from runtime.node import Node

ROWS, COLS = 172, 224
FRAME_BYTES = ROWS * COLS * (4 + 2)


@dataclass(frozen=True, kw_only=True)
class Sizes:
    frames_per_camera: int
    repeats: int
    live_secs: float
    zstd: bool
    work_secs: float = 0.01


QUICK = Sizes(frames_per_camera=90, repeats=1, live_secs=2.0, zstd=False)
FULL = Sizes(frames_per_camera=240, repeats=3, live_secs=5.0, zstd=True)


def camera_frames(count: int) -> list[tuple[str, list[Any]]]:
    """``count`` frames per camera, encoded, alternating left and right (distinct pixels)."""
    from bench.nodes import bench_images

    depth_m, ir = bench_images(ROWS, COLS)
    out = []
    for i in range(count):
        for sensor in ("left", "right"):
            msg = ToFImage(
                header=Header(stamp_nanos=i * 22_222_222, seq=i, frame_id=f"{sensor}_sensor"),
                sensor=sensor,
                depth_m=depth_m + i * 1e-4,
                ir=ir,
                fx_px=210.0,
                fy_px=210.0,
                cx_px=111.5,
                cy_px=85.5,
            )
            topic = f"{sensor}_camera/image"
            out.append((topic, encode(topic, msg)))
    return out


def _bytes(frames: list[Any]) -> int:
    return sum(memoryview(f).nbytes for f in frames[1:])


def record_bag(data: list[tuple[str, list[Any]]], path: Path, compression: str) -> float:
    """Seconds to write ``data`` with :class:`BagWriter` (close included)."""
    start = time.perf_counter()
    with BagWriter(path, compression=compression) as writer:
        for i, (topic, frames) in enumerate(data):
            writer.write_frames(topic, frames, log_time_nanos=i * 11_111_111)
    return time.perf_counter() - start


def record_raw(data: list[tuple[str, list[Any]]], path: Path, compression: str) -> float:
    """Seconds to write the same bytes with the plain ``mcap`` writer."""
    kind = CompressionType.ZSTD if compression == "zstd" else CompressionType.NONE
    start = time.perf_counter()
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=4 << 20, compression=kind)
        writer.start()
        schema = writer.register_schema("ToFImage", "", b"")
        channels = {
            topic: writer.register_channel(topic, "msgpack", schema)
            for topic in ("left_camera/image", "right_camera/image")
        }
        for i, (topic, frames) in enumerate(data):
            payload = b"".join(memoryview(x).cast("B") for x in frames[1:])
            writer.add_message(
                channels[topic], log_time=i * 11_111_111, data=payload, publish_time=0
            )
        writer.finish()
    return time.perf_counter() - start


def _row(mode: str, frames: int, nbytes: int, secs: float, **extra: Any) -> Row:
    return {
        "mode": mode,
        "frames": frames,
        "frames_per_sec": frames / secs,
        "mb_per_sec": nbytes / secs / 1e6,
        **extra,
    }


def run_record(sizes: Sizes, workdir: Path) -> list[Row]:
    data = camera_frames(sizes.frames_per_camera)
    nbytes = sum(_bytes(frames) for _, frames in data)
    rows = []
    for compression in ("none", "zstd") if sizes.zstd else ("none",):
        ours: list[float] = []
        raw: list[float] = []
        for _ in range(sizes.repeats):
            ours.append(record_bag(data, workdir / "ours.mcap", compression))
            raw.append(record_raw(data, workdir / "raw.mcap", compression))
        suffix = "" if compression == "none" else f"_{compression}"
        ratio = median(raw) / median(ours)
        rows.append(_row(f"record_bag{suffix}", len(data), nbytes, median(ours), vs_raw=ratio))
        rows.append(_row(f"record_raw_mcap{suffix}", len(data), nbytes, median(raw), vs_raw=1.0))
    bag = workdir / "cameras.mcap"
    record_bag(data, bag, "none")
    ours, raw = [], []
    for _ in range(sizes.repeats):
        count, secs = read_bag(bag)
        ours.append(secs)
        raw.append(read_raw(bag)[1])
    ratio = median(raw) / median(ours)
    rows.append(_row("read", count, nbytes, median(ours), vs_raw=ratio))
    rows.append(_row("read_raw_mcap", count, nbytes, median(raw), vs_raw=1.0))
    return rows


def read_bag(path: Path) -> tuple[int, float]:
    """Messages and seconds to read ``path`` with :class:`BagReader`, unpacked to frames."""
    start = time.perf_counter()
    count = 0
    with BagReader(path) as reader:
        for msg in reader.messages():
            msg.frames()
            count += 1
    return count, time.perf_counter() - start


def read_raw(path: Path) -> tuple[int, float]:
    """The same with the plain ``mcap`` reader and ``msgpack.unpackb`` (a third party)."""
    start = time.perf_counter()
    count = 0
    with open(path, "rb") as f:
        for _, _, message in make_reader(f).iter_messages():
            msgpack.unpackb(message.data)
            count += 1
    return count, time.perf_counter() - start


# -- live: the launcher, node processes -----------------------------------------------------------


class ReplaySink(Node):
    """Counts camera frames and times the first and last (``bench.bags:ReplaySink``)."""

    inputs = {"left": ToFImage, "right": ToFImage}
    optional_inputs = frozenset({"right"})
    outputs: dict[str, type] = {}

    class Params(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
        out_path: str = ""
        work_secs: float = 0.0  # busy work per frame, standing in for a perception stage

    def setup(self) -> None:
        self.count = 0
        self.nbytes = 0
        self.first = 0
        self.last = 0

    def _take(self, msg: ToFImage) -> None:
        if self.params.work_secs:
            end = time.perf_counter() + self.params.work_secs
            while time.perf_counter() < end:
                pass
        now = time.monotonic_ns()
        self.first = self.first or now
        self.last = now
        self.count += 1
        self.nbytes += msg.depth_m.nbytes + msg.ir.nbytes

    def on_left(self, msg: ToFImage) -> None:
        self._take(msg)

    def on_right(self, msg: ToFImage) -> None:
        self._take(msg)

    def teardown(self) -> None:
        if self.params.out_path:
            result = {
                "count": self.count,
                "bytes": self.nbytes,
                "first": self.first,
                "last": self.last,
            }
            Path(self.params.out_path).write_text(json.dumps(result))


class ImageRelay(Node):
    """Republishes each camera frame as it comes (``bench.bags:ImageRelay``)."""

    inputs = {"image": ToFImage}
    outputs = {"image": ToFImage}

    def on_image(self, msg: ToFImage) -> None:
        self.io.publish("image", msg)


def _launch(graph: dict[str, Any], **kwargs: Any) -> int:
    from cli.run import launch

    # The launcher prints its end-of-run table: to the log, not into the benchmark's.
    with launcher_log("bags") as log, contextlib.redirect_stdout(log):
        return launch(graph, source="bench.bags", log_level="WARNING", **kwargs)


def run_live_record(sizes: Sizes, workdir: Path) -> Row:
    frames = int(45 * sizes.live_secs)
    graph: dict[str, Any] = {"nodes": {}}
    for side in ("left", "right"):
        graph["nodes"][f"{side}_camera"] = {
            "impl": "bench.image_source",
            "params": {"latency_frames": frames, "throughput_frames": 0, "rate_hz": 45.0},
            "inputs": {"ack": f"{side}_sink/ack"},
        }
        graph["nodes"][f"{side}_sink"] = {
            "impl": "bench.image_sink",
            "inputs": {"image": f"{side}_camera/image"},
        }
    bag = workdir / "live.mcap"
    code = _launch(graph, record=bag, topics=r".*_camera/image")
    if code != 0:
        raise RuntimeError(f"live recording exited {code}")
    return _camera_row("record_live", bag, expected=lambda stats: 2 * frames)


def run_pipeline_record(workdir: Path) -> Row:
    root = Path(__file__).resolve().parents[1]
    graph = yaml.safe_load((root / "graph.yaml").read_text())
    scene = yaml.safe_load((root / graph["nodes"]["world"]["params"]["scene"]).read_text())
    scene.setdefault("camera", {})["frame_rate_hz"] = 45.0
    scene_path = workdir / "scene_45fps.yaml"
    scene_path.write_text(yaml.safe_dump(scene))
    graph["nodes"]["world"]["params"]["scene"] = str(scene_path)
    bag = workdir / "pipeline.mcap"
    code = _launch(graph, record=bag)
    if code != 0:
        raise RuntimeError(f"the default graph exited {code} while recording")
    # Each camera renders one frame per world state.
    return _camera_row("record_pipeline", bag, expected=lambda s: 2 * s["world/state"].messages)


def _camera_row(mode: str, bag: Path, expected: Callable[[dict[str, Any]], int]) -> Row:
    """A recording's row: both cameras' frames; ``dropped`` = expected frames not in the
    bag, plus what the recorder saw dropped or rejected."""
    with BagReader(bag) as reader:
        stats = reader.stats()
        drops = reader.drops()
    topics = ["left_camera/image", "right_camera/image"]
    recorded = sum(stats[t].messages for t in topics)
    lost = sum(
        drops.get(t, {}).get("runtime", 0) + drops.get(t, {}).get("rejected", 0) for t in topics
    )
    span = max(stats[t].last_log_nanos for t in topics) - min(
        stats[t].first_log_nanos for t in topics
    )
    nbytes = sum(stats[t].bytes for t in topics)
    dropped = expected(stats) - recorded + lost
    return _row(mode, recorded, nbytes, span / 1e9, dropped=dropped, target_fps=90.0)


def run_replay(bag: Path, workdir: Path, lockstep: bool, work_secs: float, fan_in: bool) -> Row:
    out = workdir / f"sink_{lockstep}_{work_secs}_{fan_in}.json"
    right = "relay/image" if fan_in else "right_camera/image"
    graph: dict[str, Any] = {
        "nodes": {
            "replay": {
                "impl": "replay",
                "params": {"path": str(bag), "fast": True, "lockstep": lockstep},
            },
            "sink": {
                "impl": "bench.bags:ReplaySink",
                "params": {"out_path": str(out), "work_secs": work_secs},
                "inputs": {"left": "left_camera/image", "right": right},
            },
        }
    }
    if fan_in:
        graph["nodes"]["relay"] = {
            "impl": "bench.bags:ImageRelay",
            "inputs": {"image": "right_camera/image"},
        }
    # The launcher tracks counts in both modes so the replay can wait for the sink to
    # drain before it stops the graph (as ``launch.py replay`` does).
    code = _launch(graph, lockstep=True)
    if code != 0:
        raise RuntimeError(f"replay exited {code}")
    result = json.loads(out.read_text())
    secs = (result["last"] - result["first"]) / 1e9
    mode = "replay_lockstep" if lockstep else "replay_fast"
    if fan_in:
        mode += "_fanin"
    if work_secs:
        mode += f"_work{work_secs * 1e3:g}ms"
    return _row(mode, result["count"], result["bytes"], secs, work_ms=work_secs * 1e3)


def _replay_label(point: tuple[float, bool]) -> str:
    return f"replay, {point[0] * 1e3:.0f} ms work, {'fan-in' if point[1] else 'chain'}"


def run(quick: bool) -> list[Row]:
    import bench.nodes  # noqa: F401  (registers bench.image_source and bench.image_sink)
    import nodes

    nodes.import_all()  # the default graph's nodes, recorder and replay

    sizes = QUICK if quick else FULL
    with tempfile.TemporaryDirectory(prefix="bench_bags_") as tmp:
        workdir = Path(tmp)
        rows = run_record(sizes, workdir)
        rows.append(run_live_record(sizes, workdir))
        rows.append(run_pipeline_record(workdir))
        bag = workdir / "cameras.mcap"
        replays = [(0.0, False), (0.0, True), (sizes.work_secs, False), (sizes.work_secs, True)]
        for work_secs, fan_in in progress(replays, "bench.bags", label=_replay_label):
            fast: list[Row] = []
            lock: list[Row] = []
            for _ in range(sizes.repeats):
                fast.append(run_replay(bag, workdir, False, work_secs, fan_in))
                lock.append(run_replay(bag, workdir, True, work_secs, fan_in))
            for mode_rows in (fast, lock):
                best = dict(mode_rows[0])
                best["frames_per_sec"] = median([r["frames_per_sec"] for r in mode_rows])
                best["mb_per_sec"] = median([r["mb_per_sec"] for r in mode_rows])
                best["frames"] = min(r["frames"] for r in mode_rows)
                rows.append(best)
            cost = 100.0 * (1.0 - rows[-1]["frames_per_sec"] / rows[-2]["frames_per_sec"])
            rows[-1]["lockstep_cost_pct"] = cost
    return rows


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    modes = [r["mode"] for r in rows]
    ax.barh(modes, [r["frames_per_sec"] for r in rows], color="tab:blue")
    ax.axvline(90.0, color="tab:red", linestyle="--", label="2 cameras x 45 fps")
    ax.set_xscale("log")
    ax.set_xlabel("frames per second (one frame = one camera's depth + IR)")
    ax.set_title("bag recording and replay throughput")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main(
        "bags",
        run,
        columns=[
            "mode",
            "frames",
            "frames_per_sec",
            "mb_per_sec",
            "vs_raw",
            "dropped",
            "work_ms",
            "lockstep_cost_pct",
        ],
        plot=plot,
    )
