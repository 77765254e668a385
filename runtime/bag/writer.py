"""Writing bags: the graph's frames, one MessagePack value each, into an MCAP file.

The MCAP records are the ``mcap`` library's; this layer adds the schemas a third party
needs (:mod:`runtime.bag.schema`), per-topic counts of drops and sequence gaps, a flush
every ``flush_period_secs`` so a killed recording is readable up to the last flush, and
one clear :class:`messages.errors.BagError` when the file cannot be written (a full
disk, a directory at the path): after it nothing more is written, so the file ends
at the last whole record and stays readable.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import shlex
import socket
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.writer import CompressionType, Writer

from messages.base import Message
from messages.codec import decode_header, encode, pack_single
from messages.errors import BagError, FrameDecodeError
from runtime.bag.packing import PACKING
from runtime.bag.schema import SCHEMA_ENCODING, TopicSchema, schema_for

if TYPE_CHECKING:
    from runtime.bag.message import BagMessage

log = logging.getLogger(__name__)

MESSAGE_ENCODING = "msgpack"
PROFILE = "softbubble"

COMPRESSION = {
    "none": CompressionType.NONE,
    "lz4": CompressionType.LZ4,
    "zstd": CompressionType.ZSTD,
}


def _why(err: OSError) -> str:
    if err.errno == errno.ENOSPC:
        return "the disk is full"
    if err.errno == errno.EDQUOT:
        return "the disk quota is exceeded"
    if err.errno == errno.EISDIR:
        return "it is a directory"
    return err.strerror or str(err)


@dataclass
class TopicCounts:
    """What the writer saw on one topic."""

    messages: int = 0
    bytes: int = 0
    seq_gaps: int = 0
    rejected: int = 0
    last_seq: int | None = None

    def see(self, seq: int) -> None:
        """Count a gap in ``header.seq`` before ``seq``."""
        if self.last_seq is not None and seq > self.last_seq + 1:
            self.seq_gaps += seq - self.last_seq - 1
        self.last_seq = seq


class BagWriter:
    """Writes frames to an MCAP bag; flushes a chunk at least every ``flush_period_secs``.

    Use as a context manager, or call :meth:`close`. Not thread-safe: one writer per thread.

    Raises:
        BagError: (from any method) the file cannot be opened or written; the message names
            the file and why (``the disk is full``), and says how much was kept.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size_bytes: int = 4 << 20,
        compression: str = "none",
        flush_period_secs: float = 0.5,
    ) -> None:
        if compression not in COMPRESSION:
            raise ValueError(
                f"compression must be one of {sorted(COMPRESSION)}, got {compression!r}"
            )
        if chunk_size_bytes <= 0:
            raise ValueError(f"chunk_size_bytes must be > 0, got {chunk_size_bytes}")
        if flush_period_secs <= 0:
            raise ValueError(f"flush_period_secs must be > 0, got {flush_period_secs}")
        self.path = Path(path)
        self.flush_period_secs = flush_period_secs
        self.counts: dict[str, TopicCounts] = {}
        self.runtime_drops: dict[str, int] = {}
        self.flushed_messages = 0  # on disk for sure: written before the last flush
        self._drops_written = ""
        self._closed = False
        self._failed: str | None = None
        try:
            self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as err:
            raise BagError(f"{self.path}: cannot open for writing: {_why(err)}") from err
        self._writer = Writer(
            self._file,
            chunk_size=chunk_size_bytes,
            compression=COMPRESSION[compression],
            enable_crcs=True,
        )
        with self._writing():
            self._writer.start(profile=PROFILE, library="softbubble runtime.bag")
            self._file.flush()  # a valid (empty) bag from the first moment
        self._last_flush = time.monotonic()
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, int], int] = {}
        self._topic_channel: dict[str, tuple[str, str, int]] = {}

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Turn a failed write into one clear ``BagError``; write nothing after one."""
        if self._closed:
            raise BagError(f"{self.path}: write after close")
        if self._failed is not None:
            raise BagError(self._failed)
        try:
            yield
        except OSError as err:
            self._failed = (
                f"{self.path}: cannot write: {_why(err)}; recording stopped. The bag keeps "
                f"the {self.flushed_messages} message(s) written before the last flush "
                "(`launch.py bag recover` copies them into a complete bag)"
            )
            raise BagError(self._failed) from err

    def add_run_info(
        self,
        *,
        graph_text: str = "",
        graph_source: str = "",
        command_line: str | Sequence[str] = "",
        extra: Mapping[str, str] | None = None,
    ) -> None:
        """Store the graph file and the command line (a ``softbubble.run`` metadata record)."""
        data = {
            "graph_yaml": graph_text,
            "graph_source": graph_source,
            "command_line": command_line
            if isinstance(command_line, str)
            else shlex.join(command_line),
            "started_nanos": str(time.time_ns()),
            "host": socket.gethostname(),
        }
        data.update(extra or {})
        with self._writing():
            self._writer.add_metadata("softbubble.run", data)
            self._file.flush()

    def _channel_for(
        self, topic: str, type_name: str, fingerprint: str, schema: TopicSchema | None = None
    ) -> int:
        cached = self._topic_channel.get(topic)
        if cached is not None and cached[0] == type_name and cached[1] == fingerprint:
            return cached[2]
        key = (type_name, fingerprint)
        if schema is None:
            schema = schema_for(type_name, fingerprint)
        schema_id = self._schemas.get(key)
        if schema_id is None:
            if schema.description is None:
                log.warning(
                    "%s: topic %s carries %s with fingerprint %s, not today's declaration; "
                    "stored without a field description",
                    self.path,
                    topic,
                    type_name,
                    fingerprint,
                )
            schema_id = self._writer.register_schema(type_name, SCHEMA_ENCODING, schema.to_json())
            self._schemas[key] = schema_id
        channel_id = self._channels.get((topic, schema_id))
        if channel_id is None:
            meta = {"type": type_name, "fingerprint": fingerprint, "packing": PACKING}
            channel_id = self._writer.register_channel(topic, MESSAGE_ENCODING, schema_id, meta)
            self._channels[(topic, schema_id)] = channel_id
            # A copy outside the chunks: a corrupt chunk cannot orphan the topic's later messages.
            self._writer.add_metadata(
                "softbubble.channel",
                {
                    "channel_id": str(channel_id),
                    "topic": topic,
                    "message_encoding": MESSAGE_ENCODING,
                    "packing": PACKING,
                    "schema_name": type_name,
                    "schema_encoding": SCHEMA_ENCODING,
                    "schema_data": schema.to_json().decode(),
                },
            )
        self._topic_channel[topic] = (type_name, fingerprint, channel_id)
        return channel_id

    def _add(
        self,
        topic: str,
        channel_id: int,
        payload: bytes,
        *,
        log_time_nanos: int,
        publish_time_nanos: int,
        seq: int,
    ) -> None:
        counts = self.counts.setdefault(topic, TopicCounts())
        counts.see(seq)
        self._writer.add_message(
            channel_id,
            log_time=log_time_nanos,
            data=payload,
            publish_time=max(publish_time_nanos, 0),
            sequence=seq & 0xFFFFFFFF,
        )
        counts.messages += 1
        counts.bytes += len(payload)

    def write_frames(self, topic: str, frames: Sequence[Any], log_time_nanos: int) -> bool:
        """Record one multipart message ``[topic, header, *buffers]`` as one MessagePack value.

        Frame 0 is ignored (``topic`` names the channel). A malformed frame (bad header, the
        buffers do not match the header's arrays) is counted per topic and not stored.

        Returns:
            True if stored, False if rejected.
        """
        with self._writing():
            try:
                wire = decode_header(memoryview(getattr(frames[1], "buffer", frames[1])))
                payload = pack_single(frames[1:])
            except (FrameDecodeError, TypeError, IndexError) as err:
                counts = self.counts.setdefault(topic, TopicCounts())
                counts.rejected += 1
                if counts.rejected == 1:
                    log.warning(
                        "%s: topic %s: malformed frame not recorded: %s", self.path, topic, err
                    )
                return False
            header = wire.fields.get("header")
            stamp, seq = log_time_nanos, 0
            if isinstance(header, dict):
                stamp = int(header.get("stamp_nanos", stamp))
                seq = int(header.get("seq", 0))
            channel_id = self._channel_for(topic, wire.type, wire.fp)
            self._add(
                topic,
                channel_id,
                payload,
                log_time_nanos=log_time_nanos,
                publish_time_nanos=stamp,
                seq=seq,
            )
        self.flush_if_due()
        return True

    def copy_message(self, msg: BagMessage) -> None:
        """Write a message read from another bag: its times and stored schema, today's packing.

        Raises:
            BagError: the message cannot be unpacked (names file, topic and offset).
        """
        schema = msg.channel.schema
        try:
            payload = pack_single(msg.frames())
        except FrameDecodeError as err:
            raise BagError(f"{msg.where()}: {err}") from err
        with self._writing():
            stored = TopicSchema(schema.type_name, schema.fingerprint, schema.description)
            channel_id = self._channel_for(msg.topic, schema.type_name, schema.fingerprint, stored)
            self._add(
                msg.topic,
                channel_id,
                payload,
                log_time_nanos=msg.log_time_nanos,
                publish_time_nanos=msg.publish_time_nanos,
                seq=msg.sequence,
            )
        self.flush_if_due()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Store a metadata record as is (used to carry a bag's run info over on recovery)."""
        with self._writing():
            self._writer.add_metadata(name, dict(data))

    def write_message(self, topic: str, msg: Message, log_time_nanos: int) -> bool:
        """Encode ``msg`` with the codec and record it (tests, tools, benchmarks)."""
        return self.write_frames(topic, encode(topic, msg), log_time_nanos)

    def set_runtime_drops(self, drops: Mapping[str, int]) -> None:
        """Per-topic drops as the runtime reports them (replaces the previous report)."""
        self.runtime_drops = {str(k): int(v) for k, v in drops.items()}

    def drops(self) -> dict[str, dict[str, int]]:
        """Per topic: ``runtime`` drops, ``seq_gaps`` seen here, ``rejected`` frames."""
        topics = set(self.counts) | set(self.runtime_drops)
        return {
            t: {
                "runtime": self.runtime_drops.get(t, 0),
                "seq_gaps": self.counts[t].seq_gaps if t in self.counts else 0,
                "rejected": self.counts[t].rejected if t in self.counts else 0,
            }
            for t in sorted(topics)
        }

    def _write_drops(self, final: bool) -> None:
        body = json.dumps(self.drops(), sort_keys=True)
        if body == self._drops_written and not final:
            return
        self._writer.add_metadata("softbubble.drops", {"drops": body, "final": str(final).lower()})
        self._drops_written = body

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS (survives SIGKILL, not power loss)."""
        with self._writing():
            self._write_drops(final=False)
            self._writer.flush()  # type: ignore[no-untyped-call]
            self._file.flush()
        self.flushed_messages = sum(c.messages for c in self.counts.values())
        self._last_flush = time.monotonic()

    def flush_if_due(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_period_secs:
            self.flush()

    def close(self) -> None:
        """Write the final drop counts and the summary section; close the file.

        After a failed write, only close the file: it ends at the last whole record.
        """
        if self._closed:
            return
        try:
            if self._failed is None:
                with self._writing():
                    self._write_drops(final=True)
                    self._writer.finish()  # type: ignore[no-untyped-call]
                    self._file.flush()
        finally:
            self._closed = True
            # After a failed write the buffered tail cannot reach the disk either; the file
            # ends with what was written, a prefix of the bag.
            with contextlib.suppress(OSError):
                self._file.close()
