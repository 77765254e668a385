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
import re
import shutil
import sys
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from messages.base import Message
from messages.errors import BagError
from messages.types import GraspState, PoseEstimate, TaskEvent, ToFImage
from runtime.bag import BagReader
from viz.mosaic import MosaicState, depth_range


@dataclass
class Decoded:
    """What a bag held that could not be used, per type name: messages today's classes
    cannot decode (``undecodable``), and decoded ones that cannot be drawn or converted
    (``unusable``: a NaN focal length, a stamp beyond what Foxglove's time can hold), with
    the first reason of each type."""

    undecodable: Counter[str] = field(default_factory=Counter)
    unusable: Counter[str] = field(default_factory=Counter)
    why: dict[str, str] = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.undecodable.values()) + sum(self.unusable.values())

    def guard(self, topic: str, msg: Message, use: Callable[[], object]) -> None:
        """``use()`` the message; a damaged value it cannot take is skipped and counted."""
        try:
            use()
        except (ValueError, OverflowError, TypeError, ZeroDivisionError) as err:
            self.skip(topic, msg, str(err))

    def skip(self, topic: str, msg: Message, why: str) -> None:
        name = type(msg).__name__
        self.unusable[name] += 1
        self.why.setdefault(name, f"{topic}: {why}")

    def report(self, path: Path) -> None:
        for name, count in sorted(self.undecodable.items()):
            print(
                f"warning: {path}: {count} {name} message(s) not decodable today; skipped",
                file=sys.stderr,
            )
        for name, count in sorted(self.unusable.items()):
            print(
                f"warning: {path}: {count} {name} message(s) with values that cannot be used "
                f"(first: {self.why[name]}); skipped",
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


def view_bag(
    path: Path, out: Path | None, skipped: Decoded, *, object_name: str = ""
) -> Counter[str]:
    """Log a bag into Rerun: into ``out`` (.rrd) or a spawned viewer. Returns counts per
    type; what it skips is counted in ``skipped``."""
    import rerun as rr

    from viz.rerun_log import RerunLogger, check_viewer, confirm_viewer, flush, spawn_viewer

    rec = rr.RecordingStream("softbubble", recording_id=path.stem)
    logger = RerunLogger(rec, object_name=object_name)
    if out is not None:
        with written_whole(out) as part:
            rec.save(part)
            for topic, _, msg in bag_messages(path, skipped):
                skipped.guard(topic, msg, lambda: logger.log(topic, msg))  # noqa: B023
            flush(rec)
            rec.disconnect()
    else:
        viewer = spawn_viewer(
            rec,
            instead=f"save a file with `bag view {path} --out FILE.rrd` (open it with "
            f"`rerun FILE.rrd` where there is one), or `bag export {path} --foxglove OUT.mcap`",
        )
        with ends_at_once_when_interrupted():
            try:
                for topic, _, msg in bag_messages(path, skipped):
                    check_viewer(viewer)
                    skipped.guard(topic, msg, lambda: logger.log(topic, msg))  # noqa: B023
                flush(rec, viewer=viewer)
                confirm_viewer(viewer)
            except OSError:
                rr.unregister_shutdown()  # its exit handler would wait for the viewer again
                raise
        rec.disconnect()
    return logger.logged


def export_bag(path: Path, out: Path, skipped: Decoded) -> int:
    """Write a bag's messages in Foxglove's schemas to ``out`` (MCAP); returns messages
    written; what it skips is counted in ``skipped``."""
    import foxglove

    from viz.foxglove_export import FoxgloveSink

    context = foxglove.Context()
    sink = FoxgloveSink(context)
    with written_whole(out) as part:
        writer = foxglove.open_mcap(part, allow_overwrite=True, context=context)
        try:
            for topic, log_time, msg in bag_messages(path, skipped):
                skipped.guard(topic, msg, lambda: sink.log(topic, msg, log_time))  # noqa: B023
        finally:
            writer.close()
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


def export_ros2(path: Path, out: Path, skipped: Decoded) -> int:
    """Write a bag as a ROS 2 bag (MCAP storage, CDR) in the folder ``out`` (new), with
    ``viz.ros2_export``'s standard and project messages; returns the messages written;
    what it skips is counted in ``skipped``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from viz.ros2_export import Ros2Converter

    if out.exists():
        raise FileExistsError(f"{out}: exists; a ROS 2 bag is written to a new folder")
    store = get_typestore(Stores.ROS2_HUMBLE)
    converter = Ros2Converter(store)
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

            def convert(topic: str, msg: Message, log_time: int) -> None:
                converted = list(converter.convert(topic, msg))  # all of it, or none
                if not connections:
                    write(*converter.static_tf(msg.header.stamp_nanos), log_time)  # type: ignore[attr-defined]
                for ros_topic, ros_type, value in converted:
                    write(ros_topic, ros_type, value, log_time)

            for topic, log_time, msg in bag_messages(path, skipped):
                skipped.guard(topic, msg, lambda: convert(topic, msg, log_time))  # noqa: B023
        if not written:
            raise BagError(f"{path}: no message to export")
        (part / out.name).rename(out)
    finally:
        shutil.rmtree(part, ignore_errors=True)
    return written


def video_bag(
    path: Path,
    out: Path,
    skipped: Decoded,
    *,
    fps: float = 0.0,
    scale: int = 2,
    stills: Path | None = None,
    object_name: str = "",
) -> tuple[int, tuple[int, int]]:
    """Render one mosaic per camera instant into ``out`` (MP4); returns (frames, (h, w)).

    A frame is drawn when a camera image with a newer stamp arrives, from everything
    received before it, so both bubbles' images of one instant are in the same frame.
    ``fps`` 0 takes the cameras' rate from the stamps. Depth is coloured over one range
    for the whole video (the 1st to 99th percentile of every valid depth pixel).
    ``stills`` (a folder) receives PNG frames at moments: the first and last frame, the
    first after each grasp or task event, and the first with the pose tracked (``ok`` or
    ``recovered``) after it was not; each named ``STEM_FRAME_tSECONDS_MOMENT.png``, the
    moment written on its bar too. Moments that fall on one frame (a grasp's ``stable``
    and the task's answer to it, stamped alike) are all named there, sorted, so the name
    does not depend on which of them the bag holds first. A message that cannot be drawn (undecodable, or a NaN
    where a number must be finite) is skipped and counted in ``skipped``.
    """
    samples = []
    stamps_seen = set()
    for _, _, image in bag_messages(path, Decoded()):  # counted in the pass below
        if isinstance(image, ToFImage) and not image.nonfinite_fields():
            stamps_seen.add(image.header.stamp_nanos)
            depth = image.depth_m[::4, ::4]
            samples.append(depth[np.isfinite(depth) & (depth > 0)])
    stamps = sorted(stamps_seen)
    if not stamps:
        raise BagError(f"{path}: no drawable ToFImage messages: nothing to draw")
    if fps <= 0:  # the cameras' rate: the median interval, which one wild stamp cannot move
        gaps = np.diff(np.array(stamps, dtype=np.float64)) * 1e-9
        fps = float(np.clip(1 / np.median(gaps), 1.0, 1000.0)) if len(gaps) else 30.0
    moments: dict[int, set[str]] = {0: {"first"}, len(stamps) - 1: {"last"}}  # frame -> stills
    state = MosaicState(object_name=object_name, depth_span_m=depth_range(np.concatenate(samples)))
    writer: Any = None
    frames = 0
    size = (0, 0)
    pending: int | None = None
    tracked = False

    def emit() -> None:
        nonlocal writer, frames, size
        moment = ", ".join(sorted(moments.get(frames, ()))) if stills is not None else ""
        image = state.render(scale, moment)
        if writer is None:
            size = (image.shape[0], image.shape[1])
            writer = cv2.VideoWriter(
                str(part), cv2.VideoWriter.fourcc(*"mp4v"), fps, (size[1], size[0])
            )
            if not writer.isOpened():
                raise OSError(f"{out}: OpenCV cannot write an MP4 video here")
        writer.write(image)
        if stills is not None and moment:
            stills.mkdir(parents=True, exist_ok=True)
            t = (state.stamp_nanos - (state.first_stamp_nanos or state.stamp_nanos)) * 1e-9
            slug = re.sub(r"[^A-Za-z0-9]+", "_", moment).strip("_")
            cv2.imwrite(str(stills / f"{out.stem}_{frames:05d}_t{t:05.2f}s_{slug}.png"), image)
        frames += 1

    with written_whole(out) as part:
        try:
            for topic, _, msg in bag_messages(path, skipped):
                if bad := msg.nonfinite_fields():
                    skipped.skip(topic, msg, f"non-finite {', '.join(bad)}")
                    continue
                if isinstance(msg, ToFImage):
                    if pending is not None and msg.header.stamp_nanos > pending:
                        skipped.guard(topic, msg, emit)
                    pending = max(pending or 0, msg.header.stamp_nanos)
                elif isinstance(msg, TaskEvent):
                    moments.setdefault(frames, set()).add(f"{msg.task} {msg.event}")
                elif isinstance(msg, GraspState) and msg.event:
                    moments.setdefault(frames, set()).add(f"grasp {msg.event}")
                elif isinstance(msg, PoseEstimate):
                    now_tracked = msg.status in ("ok", "recovered")
                    if now_tracked and not tracked:
                        moments.setdefault(frames, set()).add(f"pose {msg.status}")
                    tracked = now_tracked
                skipped.guard(topic, msg, lambda: state.update(topic, msg))  # noqa: B023
            if pending is not None:
                emit()
        finally:
            if writer is not None:
                writer.release()
    return frames, size


def main(args: argparse.Namespace) -> int:
    """``launch.py bag view|export|video ARGS`` (exit code 0; 1 when messages were skipped,
    counted on stderr; 2 on a bag it cannot read)."""
    command = args.bag_command
    skipped = Decoded()
    try:
        if command == "view":
            counts = view_bag(args.file, args.out, skipped, object_name=args.object)
            where = args.out or "the Rerun viewer"
            print(f"{where}: {sum(counts.values())} messages logged ({len(counts)} types)")
        elif command == "export" and args.ros2 is not None:
            written = export_ros2(args.file, args.ros2, skipped)
            print(f"{args.ros2}: a ROS 2 bag of {written} messages (`ros2 bag info {args.ros2}`)")
        elif command == "export":
            written = export_bag(args.file, args.foxglove, skipped)
            print(f"{args.foxglove}: {written} Foxglove messages")
        else:
            frames, (height, width) = video_bag(
                args.file,
                args.out,
                skipped,
                fps=args.fps,
                scale=args.scale,
                stills=args.stills,
                object_name=args.object,
            )
            print(f"{args.out}: {frames} frames of {width}x{height}")
    except (BagError, OSError) as err:
        print(f"bag {command}: {err}", file=sys.stderr)
        return 2
    skipped.report(args.file)
    return 1 if skipped.total else 0
