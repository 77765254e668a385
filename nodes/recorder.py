"""The ``recorder`` node: writes every message it receives, undecoded, into an MCAP bag.

Ports:
    inputs: any, named freely in the graph (``{t0: left_camera/image, t1: pose/pose}``);
        a raw-input node, so each message arrives as its multipart frames and any type is
        accepted. ``launch.py GRAPH --record OUT.mcap [--record-topics RE]`` adds one for you.
    outputs: none.

Wire format in the bag: see :mod:`runtime.bag` (one channel per topic, the frames as
received). The bag is flushed every ``flush_period_secs``, so killing the recorder, even
with SIGKILL, loses at most that much; a restarted recorder that finds its interrupted
bag keeps it and records to ``NAME.1.mcap`` (``.2``, ...) instead. A finished bag at
``path`` is never replaced unless ``overwrite`` is set (``--overwrite``): the graph check
refuses it, naming the file, before anything starts. Per-topic drops (reported by the
runtime) and sequence gaps are written to the bag, and a recording that dropped says so
when it stops. A write that fails (a full disk) stops the node with one line naming the
file and how much the bag keeps: everything written before the last flush.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from messages.errors import BagError, NodeError
from runtime.bag import MAGIC, BagWriter
from runtime.node import Node
from runtime.registry import register


class RecorderParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Where and how to record.

    ``graph_yaml`` and ``command_line`` are stored in the bag so it can be replayed through
    the graph it came from; the launcher fills them in. ``overwrite`` allows replacing a
    finished bag at ``path``.
    """

    path: Annotated[str, Meta(description="the bag file (MCAP) to write")]
    graph_yaml: Annotated[
        str, Meta(description="the graph stored in the bag (the launcher fills it in)")
    ] = ""
    graph_source: Annotated[str, Meta(description="the graph file's path, stored in the bag")] = ""
    command_line: Annotated[
        str, Meta(description="the launcher's command line, stored in the bag")
    ] = ""
    flush_period_secs: Annotated[
        float, Meta(description="how often written messages are flushed to the file", gt=0)
    ] = 0.5
    compression: Annotated[Literal["none", "lz4", "zstd"], Meta(description="of each chunk")] = (
        "none"
    )
    chunk_size_bytes: Annotated[int, Meta(description="MCAP chunk size", gt=0)] = 4 << 20
    overwrite: Annotated[bool, Meta(description="allow replacing a finished bag at path")] = False

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path must name the bag file, got ''")
        path = Path(self.path)
        if path.is_dir():
            raise ValueError(f"path {self.path!r} is a directory; name the bag file")
        if not self.overwrite and _finished(path):
            raise ValueError(
                f"path {self.path!r} is a finished bag; pass --overwrite (overwrite: true) "
                "to replace it, or record to another path"
            )


def _interrupted(path: Path) -> bool:
    """True for a non-empty file that does not end like a complete MCAP file."""
    try:
        size = path.stat().st_size
        if size == 0:
            return False
        with open(path, "rb") as f:
            f.seek(max(0, size - len(MAGIC)))
            return f.read() != MAGIC
    except FileNotFoundError:
        return False


def _finished(path: Path) -> bool:
    """True for a non-empty file that ends like a complete MCAP file."""
    try:
        return path.stat().st_size > 0 and not _interrupted(path)
    except FileNotFoundError:
        return False


def _next_free(path: Path) -> Path:
    """``out.1.mcap``, ``out.2.mcap``, ...: the first that does not exist."""
    n = 1
    while (candidate := path.with_name(f"{path.stem}.{n}{path.suffix}")).exists():
        n += 1
    return candidate


@register("recorder")
class Recorder(Node):
    """Records every input topic to ``path`` (MCAP); see the module docstring."""

    Params = RecorderParams
    raw_input = True
    merges_in_any_order = True  # each topic is stored in its own order; bags are per topic

    def setup(self) -> None:
        p = self.params
        path = Path(p.path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if _interrupted(path):
            # Most likely this recorder's previous incarnation (restarted after a crash) or a
            # killed run: never overwrite what it saved.
            path = _next_free(path)
            self.io.log.warning(
                "%s holds an interrupted recording; keeping it and recording to %s", p.path, path
            )
        self.path = path
        try:
            self.writer = BagWriter(
                path,
                chunk_size_bytes=p.chunk_size_bytes,
                compression=p.compression,
                flush_period_secs=p.flush_period_secs,
            )
            self.writer.add_run_info(
                graph_text=p.graph_yaml, graph_source=p.graph_source, command_line=p.command_line
            )
        except BagError as err:
            raise NodeError(f"{self.name}: {err}") from err
        # The timer flushes a quiet recording too: the last messages before a kill are on
        # disk even when nothing arrives after them.
        self.io.add_timer(p.flush_period_secs, self._flush)

    def on_raw(self, topic: str, frames: list[Any]) -> None:
        try:
            self.writer.write_frames(topic, frames, self.io.now_nanos())
        except BagError as err:
            raise NodeError(f"{self.name}: {err}") from err

    def _flush(self) -> None:
        self.writer.set_runtime_drops(self.io.drops())
        try:
            self.writer.flush()
        except BagError as err:
            raise NodeError(f"{self.name}: {err}") from err

    def teardown(self) -> None:
        if not hasattr(self, "writer"):
            return  # setup failed before the bag was opened
        self.writer.set_runtime_drops(self.io.drops())
        try:
            self.writer.close()
        except BagError as err:
            raise NodeError(f"{self.name}: {err}") from err
        total = sum(c.messages for c in self.writer.counts.values())
        lost = {
            topic: d
            for topic, d in self.writer.drops().items()
            if d["runtime"] or d["seq_gaps"] or d["rejected"]
        }
        self.io.log.info(
            "recorded %d messages on %d topics to %s",
            total,
            len(self.writer.counts),
            self.path,
        )
        for topic, d in sorted(lost.items()):
            self.io.log.warning(
                "recording DROPPED on %s: %d dropped by the runtime, %d sequence gaps, "
                "%d malformed frames",
                topic,
                d["runtime"],
                d["seq_gaps"],
                d["rejected"],
            )
