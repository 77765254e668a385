"""``viewer.rerun`` and ``viewer.foxglove``: show a live run in Rerun or Foxglove.

Ports:
    inputs: any, named freely (``{t0: left_camera/image, t1: pose/pose}``), all optional:
        a raw-input node like the recorder, so it can join any graph;
        ``launch.py GRAPH --view [TARGET]`` adds one on every topic. Each frame is decoded
        with today's classes; a frame that does not decode is counted and reported once per
        topic, and the rest go on.
    outputs: none.

``viewer.rerun`` logs with ``viz.rerun_log`` (archetypes and entity tree there) into a
spawned Rerun viewer (``target: spawn``) or an ``.rrd`` file written headless
(``target: out.rrd``). ``viewer.foxglove`` serves ``viz.foxglove_export``'s conversion on
Foxglove's live WebSocket server (``ws://HOST:PORT``; open it in the Foxglove app).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from messages.codec import decode
from messages.errors import FrameDecodeError
from runtime.node import Node
from runtime.registry import register

TEARDOWN_FLUSH_SECS = 5.0  # a closed viewer window must not hold the graph's stop


class RerunViewerParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``target``: ``spawn`` or a path ending in ``.rrd``; ``object``: the object drawn under
    the estimated pose until ground truth names one ("" for none)."""

    target: Annotated[str, Meta(description="spawn (a Rerun viewer) or a path ending in .rrd")] = (
        "spawn"
    )
    object: Annotated[
        str,
        Meta(
            description="the object drawn under the estimated pose until ground truth names one ('' for none)"
        ),
    ] = ""

    def __post_init__(self) -> None:
        if self.target != "spawn" and not self.target.endswith(".rrd"):
            raise ValueError(
                f"`target` must be 'spawn' or a path ending in .rrd, got {self.target!r}"
            )


class FoxgloveViewerParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Where Foxglove's WebSocket server listens."""

    host: Annotated[str, Meta(description="the address Foxglove's WebSocket server listens on")] = (
        "127.0.0.1"
    )
    port: Annotated[int, Meta(description="its port", ge=0, le=65535)] = 8765


class _DecodingViewer(Node):
    raw_input = True
    merges_in_any_order = True  # a picture per message; no output depends on interleaving

    def setup(self) -> None:
        self.bad_frames: Counter[str] = Counter()

    def on_raw(self, topic: str, frames: list[Any]) -> None:
        try:
            _, msg = decode(frames)
        except FrameDecodeError as err:
            if not self.bad_frames[topic]:
                self.io.log.warning("%s: %s: not shown: %s", self.name, topic, err)
            self.bad_frames[topic] += 1
            return
        self.show(topic, msg)

    def show(self, topic: str, msg: Any) -> None:
        raise NotImplementedError

    def report(self, what: str, count: int) -> None:
        self.io.log.info("%s: %d messages shown %s", self.name, count, what)
        for topic, n in sorted(self.bad_frames.items()):
            self.io.log.warning("%s: %d undecodable frame(s) on %s", self.name, n, topic)


@register("viewer.rerun")
class RerunViewer(_DecodingViewer):
    """Logs every message it receives to Rerun (see the module docstring)."""

    Params = RerunViewerParams

    def setup(self) -> None:
        import rerun as rr

        from viz.rerun_log import RerunLogger, spawn_viewer

        super().setup()
        self.rec = rr.RecordingStream("softbubble", recording_id=self.name)
        self.viewer = None
        if self.params.target == "spawn":
            self.viewer = spawn_viewer(
                self.rec, instead="use `--view FILE.rrd` (saved here) or `--view foxglove`"
            )
        else:
            Path(self.params.target).parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(self.params.target)
        self.logger = RerunLogger(self.rec, object_name=self.params.object)

    def show(self, topic: str, msg: Any) -> None:
        self.logger.log(topic, msg)

    def teardown(self) -> None:
        from viz.rerun_log import flush

        try:
            flushed = flush(self.rec, deadline_secs=TEARDOWN_FLUSH_SECS, viewer=self.viewer)
        except OSError as err:
            self.io.log.warning("%s: %s", self.name, err)
            flushed = True
        if not flushed:
            self.io.log.warning(
                "%s: the Rerun viewer took no data for %g s; the rest is dropped",
                self.name,
                TEARDOWN_FLUSH_SECS,
            )
        self.rec.disconnect()
        self.report(f"in Rerun ({self.params.target})", sum(self.logger.logged.values()))


@register("viewer.foxglove")
class FoxgloveViewer(_DecodingViewer):
    """Serves every message it receives to the Foxglove app (see the module docstring)."""

    Params = FoxgloveViewerParams

    def setup(self) -> None:
        import foxglove

        from viz.foxglove_export import FoxgloveSink

        super().setup()
        self.context = foxglove.Context()
        self.server = foxglove.start_server(
            name="softbubble", host=self.params.host, port=self.params.port, context=self.context
        )
        self.io.log.info(
            "%s: Foxglove server on ws://%s:%d", self.name, self.params.host, self.server.port
        )
        self.sink = FoxgloveSink(self.context)

    def show(self, topic: str, msg: Any) -> None:
        self.sink.log(topic, msg, self.io.now_nanos())

    def teardown(self) -> None:
        self.server.stop()
        self.report("on the Foxglove server", self.sink.written)
