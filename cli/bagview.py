"""``launch.py bag view|export|video``; the ``--view`` option is ``cli.taps``.

    python launch.py bag view run.mcap [--out run.rrd]        # Rerun viewer, or a file
    python launch.py bag export run.mcap --foxglove out.mcap  # Foxglove's schemas
    python launch.py bag video run.mcap --out run.mp4 [--stills DIR]

The command-line layer of ``viz``: it reads bags (through ``runtime.bag``'s reader, as
``bag echo`` does) and hands decoded messages to ``viz.rerun_log``,
``viz.foxglove_export`` and ``viz.mosaic``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from messages.base import Message
from messages.errors import BagError
from messages.types import GraspState, TaskEvent, ToFImage
from runtime.bag import BagReader
from viz.mosaic import MosaicState


@dataclass
class Decoded:
    """What a bag held that today's classes could not decode, per type name."""

    undecodable: Counter[str]

    def report(self, path: Path) -> None:
        for name, count in sorted(self.undecodable.items()):
            print(
                f"warning: {path}: {count} {name} message(s) not decodable today; skipped",
                file=sys.stderr,
            )


def bag_messages(path: Path, skipped: Decoded) -> Iterator[tuple[str, int, Message]]:
    """``(topic, log_time_nanos, message)`` of every decodable message, in file order."""
    with BagReader(path) as reader:
        for msg in reader.messages():
            try:
                decoded = msg.decode()
            except BagError:
                skipped.undecodable[msg.channel.schema.type_name] += 1
                continue
            yield msg.topic, msg.log_time_nanos, decoded


@contextmanager
def ends_at_once_when_interrupted() -> Iterator[None]:
    """Ctrl-C or SIGTERM (raised as ``SystemExit``) inside: the process ends at once, with
    its exit code. Rerun's stream to a viewer that takes nothing waits 5 s when dropped,
    and its exit handler waits again."""
    try:
        yield
    except KeyboardInterrupt:
        code: object = 130
    except SystemExit as stop:
        code = stop.code
    else:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code if isinstance(code, int) else 1)


@contextmanager
def written_whole(out: Path) -> Iterator[Path]:
    """A path beside ``out`` to write into, renamed to ``out`` when the block ends and
    removed when it fails: a failed command leaves no stub, and a file already at ``out``
    stays as it was. The name keeps ``out``'s suffix (OpenCV picks the format by it)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(f".{out.stem}.part{out.suffix}")
    try:
        yield part
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    part.replace(out)


def view_bag(path: Path, out: Path | None, *, object_name: str = "") -> Counter[str]:
    """Log a bag into Rerun: into ``out`` (.rrd) or a spawned viewer. Returns counts per type."""
    import rerun as rr

    from viz.rerun_log import RerunLogger, flush, spawn_viewer

    rec = rr.RecordingStream("softbubble", recording_id=path.stem)
    logger = RerunLogger(rec, object_name=object_name)
    skipped = Decoded(Counter())
    if out is not None:
        with written_whole(out) as part:
            rec.save(part)
            for topic, _, msg in bag_messages(path, skipped):
                logger.log(topic, msg)
            flush(rec)
            rec.disconnect()
    else:
        spawn_viewer(
            rec,
            instead=f"save a file with `bag view {path} --out FILE.rrd` (open it with "
            f"`rerun FILE.rrd` where there is one), or `bag export {path} --foxglove OUT.mcap`",
        )
        with ends_at_once_when_interrupted():
            for topic, _, msg in bag_messages(path, skipped):
                logger.log(topic, msg)
            flush(rec)
        rec.disconnect()
    skipped.report(path)
    return logger.logged


def export_bag(path: Path, out: Path) -> int:
    """Write a bag's messages in Foxglove's schemas to ``out`` (MCAP); returns messages written."""
    import foxglove

    from viz.foxglove_export import FoxgloveSink

    context = foxglove.Context()
    sink = FoxgloveSink(context)
    skipped = Decoded(Counter())
    with written_whole(out) as part:
        writer = foxglove.open_mcap(part, allow_overwrite=True, context=context)
        try:
            for topic, log_time, msg in bag_messages(path, skipped):
                sink.log(topic, msg, log_time)
        finally:
            writer.close()
    skipped.report(path)
    return sink.written


def latched() -> tuple[Any, ...]:
    """The QoS of ``/tf_static`` (transient local, keep last 1), so that ``ros2 bag play``
    hands the camera mounts to a subscriber that joins late, as tf2 expects."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    never = QosTime(0, 0)
    return (
        Qos(
            QosHistory.KEEP_LAST,
            1,
            QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL,
            never,
            never,
            QosLiveliness.AUTOMATIC,
            never,
            False,
        ),
    )


def export_ros2(path: Path, out: Path) -> int:
    """Write a bag as a ROS 2 bag (MCAP storage, CDR) in the folder ``out`` (new), with
    ``viz.ros2_export``'s standard and project messages; returns the messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from viz.ros2_export import Ros2Converter

    if out.exists():
        raise FileExistsError(f"{out}: exists; a ROS 2 bag is written to a new folder")
    store = get_typestore(Stores.ROS2_HUMBLE)
    converter = Ros2Converter(store)
    skipped = Decoded(Counter())
    written = 0
    # The bag's files are named after its folder: it is written whole in a folder of that
    # name inside a part folder, then moved into place; a failure leaves nothing.
    part = out.with_name(f".{out.name}.part")
    shutil.rmtree(part, ignore_errors=True)
    part.mkdir(parents=True)
    try:
        with Writer(part / out.name, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            connections: dict[str, Any] = {}

            def write(topic: str, ros_type: str, value: Any, log_time: int) -> None:
                nonlocal written
                connection = connections.get(topic)
                if connection is None:
                    qos = latched() if topic == "/tf_static" else ()
                    connection = writer.add_connection(
                        topic, ros_type, typestore=store, offered_qos_profiles=qos
                    )
                    connections[topic] = connection
                elif connection.msgtype != ros_type:
                    raise BagError(
                        f"{path}: {topic} would carry {ros_type} and {connection.msgtype}"
                    )
                writer.write(connection, log_time, store.serialize_cdr(value, ros_type))
                written += 1

            for topic, log_time, msg in bag_messages(path, skipped):
                if not connections:
                    write(*converter.static_tf(msg.header.stamp_nanos), log_time)  # type: ignore[attr-defined]
                for ros_topic, ros_type, value in converter.convert(topic, msg):
                    write(ros_topic, ros_type, value, log_time)
        if not written:
            raise BagError(f"{path}: no message to export")
        (part / out.name).rename(out)
    finally:
        shutil.rmtree(part, ignore_errors=True)
    skipped.report(path)
    return written


def video_bag(
    path: Path,
    out: Path,
    *,
    fps: float = 0.0,
    scale: int = 2,
    stills: Path | None = None,
    object_name: str = "",
) -> tuple[int, tuple[int, int]]:
    """Render one mosaic per camera instant into ``out`` (MP4); returns (frames, (h, w)).

    A frame is drawn when a camera image with a newer stamp arrives, from everything
    received before it, so both bubbles' images of one instant are in the same frame.
    ``fps`` 0 takes the cameras' rate from the stamps. ``stills`` (a folder) receives
    PNG frames: the first, the first one after each grasp or task event, and the last.
    """
    skipped = Decoded(Counter())
    with BagReader(path) as reader:
        cameras = [t for t, s in reader.topics().items() if s.type_name == ToFImage.__name__]
        stamps = sorted({m.decode().header.stamp_nanos for m in reader.messages(cameras)})  # type: ignore[attr-defined]
    if not stamps:
        raise BagError(f"{path}: no ToFImage messages: nothing to draw")
    if fps <= 0:
        span = (stamps[-1] - stamps[0]) * 1e-9
        fps = (len(stamps) - 1) / span if len(stamps) > 1 and span > 0 else 30.0
    keep = {0, len(stamps) - 1}  # frame indices to save as stills; events add theirs
    state = MosaicState(object_name=object_name)
    writer: Any = None
    frames = 0
    size = (0, 0)
    pending: int | None = None

    def emit() -> None:
        nonlocal writer, frames, size
        image = state.render(scale)
        if writer is None:
            size = (image.shape[0], image.shape[1])
            writer = cv2.VideoWriter(
                str(part), cv2.VideoWriter.fourcc(*"mp4v"), fps, (size[1], size[0])
            )
            if not writer.isOpened():
                raise OSError(f"{out}: OpenCV cannot write an MP4 video here")
        writer.write(image)
        if stills is not None and frames in keep:
            stills.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(stills / f"{out.stem}_{frames:05d}.png"), image)
        frames += 1

    with written_whole(out) as part:
        try:
            for topic, _, msg in bag_messages(path, skipped):
                if isinstance(msg, ToFImage):
                    if pending is not None and msg.header.stamp_nanos > pending:
                        emit()
                    pending = max(pending or 0, msg.header.stamp_nanos)
                elif isinstance(msg, TaskEvent) or (isinstance(msg, GraspState) and msg.event):
                    keep.add(frames)
                state.update(topic, msg)
            if pending is not None:
                emit()
        finally:
            if writer is not None:
                writer.release()
    skipped.report(path)
    return frames, size


def main(args: argparse.Namespace) -> int:
    """``launch.py bag view|export|video ARGS`` (exit code 0, or 2 on a bad bag)."""
    command = args.bag_command
    try:
        if command == "view":
            counts = view_bag(args.file, args.out, object_name=args.object)
            where = args.out or "the Rerun viewer"
            print(f"{where}: {sum(counts.values())} messages logged ({len(counts)} types)")
        elif command == "export" and args.ros2 is not None:
            written = export_ros2(args.file, args.ros2)
            print(f"{args.ros2}: a ROS 2 bag of {written} messages (`ros2 bag info {args.ros2}`)")
        elif command == "export":
            written = export_bag(args.file, args.foxglove)
            print(f"{args.foxglove}: {written} Foxglove messages")
        else:
            frames, (height, width) = video_bag(
                args.file,
                args.out,
                fps=args.fps,
                scale=args.scale,
                stills=args.stills,
                object_name=args.object,
            )
            print(f"{args.out}: {frames} frames of {width}x{height}")
    except (BagError, OSError) as err:
        print(f"bag {command}: {err}", file=sys.stderr)
        return 2
    return 0
