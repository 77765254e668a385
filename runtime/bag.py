"""MCAP bags: write the graph's frames as received, read them back with or without today's classes.

Layout of a bag (an ordinary MCAP file, readable by any MCAP reader):

- one **channel per topic** (``message_encoding`` ``"msgpack"``), whose metadata carries
  ``type``, ``fingerprint`` and ``packing``;
- one **schema per message type and fingerprint**: name = type name, encoding
  ``"softbubble.description+json"``, data = JSON ``{"type", "fingerprint", "description",
  "packing"}`` where ``description`` is :func:`messages.base.describe` of the type at record
  time, so an old bag lists and decodes after a field changed (to plain dicts and numpy
  arrays, see :meth:`BagMessage.decode_plain`);
- **message payload** (``packing`` ``"softbubble-multipart-v1"``): the multipart frame as
  received minus the topic frame (the channel names the topic)::

      u32 LE   n                     number of frames that follow (header + one per array)
      n x u64 LE                     byte length of each frame
      frame 1  MessagePack header    exactly as on the wire (decodes with plain msgpack)
      frame 2+ raw array buffers     exactly as on the wire (no re-encoding)

  MCAP ``log_time`` is the recorder's receive time, ``publish_time`` the message's
  ``header.stamp_nanos`` and ``sequence`` its ``header.seq``;
- **metadata records**: ``softbubble.run`` (graph file text and path, the command line as
  a JSON list, start time, host), ``softbubble.channel`` (a copy of every channel and its
  schema, written outside the chunks so a corrupt first chunk does not orphan a topic),
  and ``softbubble.drops`` (per-topic drops reported by the runtime, sequence gaps seen by
  the recorder, frames rejected as malformed), rewritten at every flush; the last one wins.

The writer flushes the open chunk every ``flush_period_secs``, so a SIGKILLed recording is
readable up to the last flush. The reader walks the file record by record and never needs
the summary section: a file cut anywhere is recovered up to its last whole chunk, a chunk
whose CRC or compression is broken is skipped with a warning and the number of messages it
held (from its message index), and every error is a :class:`messages.errors.BagError`
naming the file, the topic where there is one, and the byte offset.
"""

from __future__ import annotations

import json
import logging
import mmap
import os
import re
import shlex
import socket
import struct
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
from mcap.writer import CompressionType, Writer

from messages.base import Message
from messages.codec import decode, decode_header
from messages.errors import BagError, FrameDecodeError

log = logging.getLogger(__name__)

PACKING = "softbubble-multipart-v1"
SCHEMA_ENCODING = "softbubble.description+json"
MESSAGE_ENCODING = "msgpack"
PROFILE = "softbubble"
MAGIC = b"\x89MCAP0\r\n"

# MCAP opcodes (https://mcap.dev/spec).
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_MESSAGE_INDEX, _CHUNK_INDEX, _ATTACHMENT, _ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
_STATISTICS, _METADATA, _METADATA_INDEX, _SUMMARY_OFFSET, _DATA_END = 0x0B, 0x0C, 0x0D, 0x0E, 0x0F
_KNOWN_OPCODES = frozenset(range(0x01, 0x10))

_COMPRESSION = {
    "none": CompressionType.NONE,
    "lz4": CompressionType.LZ4,
    "zstd": CompressionType.ZSTD,
}


# -- payload packing ---------------------------------------------------------------------------


def _as_buffer(frame: Any) -> memoryview:
    """bytes, memoryview or ``zmq.Frame`` to a flat byte view."""
    view = memoryview(getattr(frame, "buffer", frame))
    return view if view.format == "B" and view.ndim == 1 else view.cast("B")


def pack_frames(frames: Sequence[Any]) -> bytes:
    """Pack ``[header, *buffers]`` (no topic frame) into one MCAP payload (see module doc)."""
    views = [_as_buffer(f) for f in frames]
    prefix = struct.pack(f"<I{len(views)}Q", len(views), *(v.nbytes for v in views))
    return b"".join([prefix, *views])


def unpack_frames(payload: bytes | memoryview) -> list[memoryview]:
    """Split an MCAP payload back into ``[header, *buffers]`` views (no copy).

    Raises:
        ValueError: the payload is shorter than its frame table says.
    """
    view = memoryview(payload)
    if view.nbytes < 4:
        raise ValueError(f"payload of {view.nbytes} bytes has no frame count")
    (count,) = struct.unpack_from("<I", view, 0)
    table_end = 4 + 8 * count
    if count == 0 or table_end > view.nbytes:
        raise ValueError(f"payload of {view.nbytes} bytes cannot hold {count} frames")
    lengths = struct.unpack_from(f"<{count}Q", view, 4)
    if table_end + sum(lengths) != view.nbytes:
        raise ValueError(
            f"payload of {view.nbytes} bytes, its frame table adds up to {table_end + sum(lengths)}"
        )
    frames = []
    pos = table_end
    for length in lengths:
        frames.append(view[pos : pos + length])
        pos += length
    return frames


# -- schemas and channels ------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicSchema:
    """What a bag knows of the type on one channel, independent of today's classes."""

    type_name: str
    fingerprint: str
    description: dict[str, Any] | None

    def to_json(self) -> bytes:
        return json.dumps(
            {
                "type": self.type_name,
                "fingerprint": self.fingerprint,
                "description": self.description,
                "packing": PACKING,
            },
            sort_keys=True,
        ).encode()

    @staticmethod
    def from_json(data: bytes | str, name: str = "") -> TopicSchema:
        try:
            obj = json.loads(data) if data else {}
        except ValueError:
            obj = {}
        if not isinstance(obj, dict):
            obj = {}
        description = obj.get("description")
        return TopicSchema(
            type_name=str(obj.get("type", name)),
            fingerprint=str(obj.get("fingerprint", "")),
            description=description if isinstance(description, dict) else None,
        )

    def array_names(self) -> set[str] | None:
        """Names of the array fields per the stored description (``None`` if unknown)."""
        if not self.description:
            return None
        fields = self.description.get("fields", [])
        return {
            str(item[0])
            for item in (fields if isinstance(fields, list) else [])
            if isinstance(item, list)
            and len(item) == 2
            and isinstance(item[1], dict)
            and "array" in item[1]
        }

    def current_class(self) -> type[Message] | None:
        """Today's class of this type if its fingerprint still matches, else ``None``."""
        cls = Message.registry.get(self.type_name)
        if cls is None or cls.schema().fingerprint != self.fingerprint:
            return None
        return cls


def schema_for(type_name: str, fingerprint: str) -> TopicSchema:
    """The schema to store for frames of ``type_name``/``fingerprint`` seen on the wire."""
    cls = Message.registry.get(type_name)
    description = None
    if cls is not None and cls.schema().fingerprint == fingerprint:
        description = cls.schema().description
    return TopicSchema(type_name, fingerprint, description)


@dataclass(frozen=True)
class ChannelInfo:
    channel_id: int
    topic: str
    schema: TopicSchema
    message_encoding: str = MESSAGE_ENCODING
    offset: int = -1  # file offset of the record that declared it (-1: inside a chunk)


# -- writing -------------------------------------------------------------------------------------


@dataclass
class TopicCounts:
    messages: int = 0
    bytes: int = 0
    seq_gaps: int = 0
    rejected: int = 0
    last_seq: int | None = None


class BagWriter:
    """Writes frames to an MCAP bag; flushes a chunk at least every ``flush_period_secs``.

    Use as a context manager, or call :meth:`close`. Not thread-safe: one writer per thread.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size_bytes: int = 4 << 20,
        compression: str = "none",
        flush_period_secs: float = 0.5,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(
                f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}"
            )
        if chunk_size_bytes <= 0:
            raise ValueError(f"chunk_size_bytes must be > 0, got {chunk_size_bytes}")
        if flush_period_secs <= 0:
            raise ValueError(f"flush_period_secs must be > 0, got {flush_period_secs}")
        self.path = Path(path)
        try:
            self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as err:
            raise BagError(f"{self.path}: cannot open for writing: {err}") from err
        self._writer = Writer(
            self._file,
            chunk_size=chunk_size_bytes,
            compression=_COMPRESSION[compression],
            enable_crcs=True,
        )
        self._writer.start(profile=PROFILE, library="softbubble runtime.bag")
        self._file.flush()  # a valid (empty) bag from the first moment
        self.flush_period_secs = flush_period_secs
        self._last_flush = time.monotonic()
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, int], int] = {}
        self._topic_channel: dict[str, tuple[str, str, int]] = {}
        self.counts: dict[str, TopicCounts] = {}
        self.runtime_drops: dict[str, int] = {}
        self._drops_written: str = ""
        self._closed = False

    # -- context manager
    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

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
            self._writer.add_metadata(
                "softbubble.channel",
                {
                    "channel_id": str(channel_id),
                    "topic": topic,
                    "message_encoding": MESSAGE_ENCODING,
                    "schema_name": type_name,
                    "schema_encoding": SCHEMA_ENCODING,
                    "schema_data": schema.to_json().decode(),
                },
            )
        self._topic_channel[topic] = (type_name, fingerprint, channel_id)
        return channel_id

    def write_frames(self, topic: str, frames: Sequence[Any], log_time_nanos: int) -> bool:
        """Record one multipart message ``[topic, header, *buffers]`` as received.

        Frame 0 is ignored (``topic`` names the channel). A malformed frame (bad header, the
        buffers do not match the header's arrays) is counted per topic and not stored.

        Returns:
            True if stored, False if rejected.
        """
        if self._closed:
            raise BagError(f"{self.path}: write after close")
        counts = self.counts.setdefault(topic, TopicCounts())
        try:
            wire = decode_header(_as_buffer(frames[1]))
            buffers = frames[2:]
            if len(buffers) != len(wire.arrays):
                raise FrameDecodeError(
                    f"header lists {len(wire.arrays)} arrays, got {len(buffers)} buffers"
                )
            for (name, dtype, shape), buf in zip(wire.arrays, buffers, strict=True):
                want = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
                if _as_buffer(buf).nbytes != want:
                    raise FrameDecodeError(
                        f"array {name}: buffer size does not match {shape} {dtype}"
                    )
        except (FrameDecodeError, TypeError, ValueError, IndexError) as err:
            counts.rejected += 1
            if counts.rejected == 1:
                log.warning("%s: topic %s: malformed frame not recorded: %s", self.path, topic, err)
            return False
        header = wire.fields.get("header")
        stamp, seq = log_time_nanos, 0
        if isinstance(header, dict):
            stamp = int(header.get("stamp_nanos", stamp))
            seq = int(header.get("seq", 0))
        if counts.last_seq is not None and seq > counts.last_seq + 1:
            counts.seq_gaps += seq - counts.last_seq - 1
        counts.last_seq = seq
        channel_id = self._channel_for(topic, wire.type, wire.fp)
        payload = pack_frames(frames[1:])
        self._writer.add_message(
            channel_id,
            log_time=log_time_nanos,
            data=payload,
            publish_time=max(stamp, 0),
            sequence=seq & 0xFFFFFFFF,
        )
        counts.messages += 1
        counts.bytes += len(payload)
        self.flush_if_due()
        return True

    def copy_message(self, msg: BagMessage) -> None:
        """Write a message read from another bag as it is: payload, times, stored schema."""
        if self._closed:
            raise BagError(f"{self.path}: write after close")
        schema = msg.channel.schema
        channel_id = self._channel_for(msg.topic, schema.type_name, schema.fingerprint, schema)
        counts = self.counts.setdefault(msg.topic, TopicCounts())
        if counts.last_seq is not None and msg.sequence > counts.last_seq + 1:
            counts.seq_gaps += msg.sequence - counts.last_seq - 1
        counts.last_seq = msg.sequence
        self._writer.add_message(
            channel_id,
            log_time=msg.log_time_nanos,
            data=bytes(msg.payload),
            publish_time=msg.publish_time_nanos,
            sequence=msg.sequence,
        )
        counts.messages += 1
        counts.bytes += msg.payload.nbytes
        self.flush_if_due()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Store a metadata record as is (used to carry a bag's run info over on recovery)."""
        self._writer.add_metadata(name, dict(data))

    def write_message(self, topic: str, msg: Message, log_time_nanos: int) -> bool:
        """Encode ``msg`` with the codec and record it (tests, tools, benchmarks)."""
        from messages.codec import encode

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
        self._write_drops(final=False)
        self._writer.flush()  # type: ignore[no-untyped-call]
        self._last_flush = time.monotonic()

    def flush_if_due(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_period_secs:
            self.flush()

    def close(self) -> None:
        """Write the final drop counts and the summary section; close the file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._write_drops(final=True)
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()


# -- reading -------------------------------------------------------------------------------------


@dataclass
class BagMessage:
    """One recorded message; ``payload`` is a view on the file or the decompressed chunk."""

    topic: str
    channel: ChannelInfo
    log_time_nanos: int
    publish_time_nanos: int
    sequence: int
    payload: memoryview
    offset: int  # file offset of the chunk (or of the message record outside chunks)
    path: Path
    chunk_pos: int = -1  # offset of the record in the decompressed chunk (-1: not in one)

    def position(self) -> str:
        """``offset N (+M in the chunk)``: where the message is in the file."""
        inside = f" (+{self.chunk_pos} in the chunk)" if self.chunk_pos >= 0 else ""
        return f"offset {self.offset}{inside}"

    def where(self) -> str:
        """``FILE: topic T: message at offset N (+M in the chunk)`` for error messages."""
        return f"{self.path}: topic {self.topic}: message at {self.position()}"

    def frames(self) -> list[memoryview]:
        """``[header, *buffers]`` as received on the wire (no topic frame)."""
        try:
            return unpack_frames(self.payload)
        except ValueError as err:
            raise BagError(f"{self.where()}: {err}") from err

    def wire_frames(self, topic: str | None = None) -> list[Any]:
        """The full multipart message ``[topic, header, *buffers]``, ready to publish."""
        return [(topic or self.topic).encode(), *self.frames()]

    def header(self) -> dict[str, Any]:
        """Frame 1 decoded with the plain ``msgpack`` package."""
        try:
            obj = msgpack.unpackb(self.frames()[0], raw=False)
        except (ValueError, TypeError, msgpack.FormatError, msgpack.StackError) as err:
            raise BagError(f"{self.where()}: header is not MessagePack: {err}") from err
        if not isinstance(obj, dict) or not {"type", "fields", "arrays"} <= set(obj):
            raise BagError(f"{self.where()}: header is not a frame header")
        return obj

    def decode_plain(self) -> dict[str, Any]:
        """Decode without today's classes: scalar fields as plain values, arrays as numpy views.

        The stored description is checked against the header (an array it does not declare
        is an error), so a bag decodes after the type's fields changed.
        """
        frames = self.frames()
        head = self.header()
        arrays, fields = head["arrays"], head["fields"]
        if (
            not isinstance(fields, dict)
            or not isinstance(arrays, list)
            or not all(isinstance(a, list) and len(a) == 3 for a in arrays)
        ):
            raise BagError(f"{self.where()}: header fields or arrays are malformed")
        if len(arrays) != len(frames) - 1:
            raise BagError(
                f"{self.where()}: header lists {len(arrays)} arrays, payload has {len(frames) - 1}"
            )
        declared = self.channel.schema.array_names()
        out: dict[str, Any] = dict(fields)
        for (name, dtype_str, shape), buf in zip(arrays, frames[1:], strict=True):
            if not isinstance(name, str):
                raise BagError(f"{self.where()}: array name {name!r} is not a string")
            if declared is not None and name not in declared:
                raise BagError(
                    f"{self.where()}: array {name!r} is not in the stored description "
                    f"of {self.channel.schema.type_name}"
                )
            try:
                dtype = np.dtype(dtype_str)
                if dtype.hasobject:
                    raise TypeError("object dtype")
                out[name] = np.frombuffer(buf, dtype=dtype).reshape(shape)
            except (TypeError, ValueError) as err:
                raise BagError(f"{self.where()}: array {name!r}: {err}") from err
        return out

    def decode(self) -> Message:
        """Decode into today's message class (fingerprint checked).

        Raises:
            BagError: the type is unknown today or its fields changed since the recording
                (use :meth:`decode_plain`), or the frame is malformed.
        """
        try:
            return decode(self.wire_frames())[1]
        except FrameDecodeError as err:
            raise BagError(f"{self.where()}: {err}") from err


@dataclass
class TopicStats:
    """Per-topic figures from a full pass over a bag."""

    topic: str
    type_name: str
    fingerprint: str
    messages: int = 0
    bytes: int = 0
    first_log_nanos: int = 0
    last_log_nanos: int = 0
    seq_gaps: int = 0
    last_seq: int | None = None

    @property
    def rate_hz(self) -> float:
        span = (self.last_log_nanos - self.first_log_nanos) / 1e9
        return (self.messages - 1) / span if self.messages > 1 and span > 0 else 0.0


@dataclass
class _ChunkRef:
    offset: int
    length: int  # of the record, opcode and length field included
    start_nanos: int
    end_nanos: int
    index_counts: dict[int, int] = field(default_factory=dict)  # channel -> messages


Warn = Callable[[str], None]


class BagReader:
    """Reads a bag written by :class:`BagWriter` (or any MCAP file with a msgpack encoding).

    Opening walks the top level of the file once (no decompression): chunks, metadata,
    channels, the summary if there is one. A file cut short is read up to its last whole
    record, with a warning. Problems are collected in :attr:`problems` and passed to ``warn``
    (default: ``logging.warning``).
    """

    def __init__(self, path: str | Path, *, warn: Warn | None = None) -> None:
        self.path = Path(path)
        self._warn_fn = warn or (lambda text: log.warning("%s", text))
        self.problems: list[str] = []
        self.lost_messages = 0
        self.lost_unknown = False
        try:
            with open(self.path, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                if size < len(MAGIC):
                    raise BagError(f"{self.path}: not an MCAP file ({size} bytes)")
                self._mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except OSError as err:
            raise BagError(f"{self.path}: cannot open: {err}") from err
        self._view = memoryview(self._mm)
        self.size = size
        if bytes(self._view[:8]) != MAGIC:
            raise BagError(f"{self.path}: not an MCAP file (bad magic at offset 0)")
        self.channels: dict[int, ChannelInfo] = {}
        self._schemas: dict[int, tuple[str, str, bytes]] = {}  # id -> (name, encoding, data)
        self._pending_channels: dict[int, tuple[str, str, int, dict[str, str], int]] = {}
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.chunks: list[_ChunkRef] = []
        self._loose_messages: list[int] = []  # offsets of messages outside chunks
        self.has_summary = False
        self.statistics_messages: int | None = None
        self._scan()

    def close(self) -> None:
        """Unmap the file (messages still referenced keep it mapped until they are freed)."""
        try:
            self._view.release()
            self._mm.close()
        except BufferError:
            pass  # a BagMessage payload still points into the map; the GC unmaps it later

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _warn(self, text: str) -> None:
        self.problems.append(text)
        self._warn_fn(text)

    # -- top-level scan
    def _summary_chunk_offsets(self) -> list[int] | None:
        """Chunk offsets from the summary's chunk indexes, if the file has an intact footer."""
        v, size = self._view, self.size
        footer = size - 8 - 29
        if footer < 8 or bytes(v[size - 8 :]) != MAGIC or v[footer] != _FOOTER:
            return None
        summary_start, _ = struct.unpack_from("<QQ", v, footer + 9)
        if not 8 <= summary_start < footer:
            return None
        offsets = []
        pos = summary_start
        while pos + 9 <= footer:
            opcode, length = struct.unpack_from("<BQ", v, pos)
            if pos + 9 + length > footer:
                return None
            if opcode == _CHUNK_INDEX:
                offsets.append(struct.unpack_from("<Q", v, pos + 9 + 16)[0])
            pos += 9 + length
        return offsets

    def _resync(self, pos: int, summary_offsets: list[int] | None) -> int | None:
        """The offset of the next readable chunk after a broken record at ``pos``."""
        if summary_offsets is not None:
            later = [o for o in summary_offsets if o > pos]
            return min(later) if later else None
        probe = pos + 1
        while True:
            probe = self._mm.find(b"\x06", probe)
            if probe < 0 or probe + 9 > self.size:
                return None
            (length,) = struct.unpack_from("<Q", self._view, probe + 1)
            if probe + 9 + length <= self.size and self._plausible_chunk(probe, length):
                return probe
            probe += 1

    def _plausible_chunk(self, pos: int, length: int) -> bool:
        try:
            body = self._view[pos + 9 : pos + 9 + length]
            _, _, usize, _, clen = struct.unpack_from("<QQQII", body, 0)
            if clen > 8:
                return False
            comp = bytes(body[32 : 32 + clen]).decode()
            (rlen,) = struct.unpack_from("<Q", body, 32 + clen)
            return comp in ("", "zstd", "lz4") and 40 + clen + rlen == length and usize < 1 << 34
        except (struct.error, UnicodeDecodeError):
            return False

    def _scan(self) -> None:
        v, size = self._view, self.size
        summary_offsets = self._summary_chunk_offsets()
        pos = 8
        last_chunk: _ChunkRef | None = None
        in_summary = False
        while pos < size:
            if pos + 9 > size:
                self._truncated(pos, "a record header")
                break
            opcode, length = struct.unpack_from("<BQ", v, pos)
            end = pos + 9 + length
            if opcode not in _KNOWN_OPCODES or end > size:
                if end > size and opcode in _KNOWN_OPCODES and summary_offsets is None:
                    self._truncated(pos, f"a record (opcode 0x{opcode:02x}) of {length} bytes")
                    break
                nxt = self._resync(pos, summary_offsets)
                self._warn(
                    f"{self.path}: broken record at offset {pos} (opcode 0x{opcode:02x}, "
                    f"length {length}); "
                    + (f"resuming at offset {nxt}" if nxt else "nothing readable after it")
                )
                self.lost_unknown = True
                if nxt is None:
                    break
                pos = nxt
                continue
            body = v[pos + 9 : end]
            try:
                if opcode == _CHUNK:
                    start, stop = struct.unpack_from("<QQ", body, 0)
                    last_chunk = _ChunkRef(pos, end - pos, start, stop)
                    self.chunks.append(last_chunk)
                elif opcode == _MESSAGE_INDEX and last_chunk is not None:
                    channel_id, nbytes = struct.unpack_from("<HI", body, 0)
                    last_chunk.index_counts[channel_id] = nbytes // 16
                elif opcode == _MESSAGE:
                    self._loose_messages.append(pos)
                elif opcode == _SCHEMA:
                    self._read_schema(body)
                elif opcode == _CHANNEL:
                    self._read_channel(body, pos)
                elif opcode == _METADATA:
                    self._read_metadata(body, pos)
                elif opcode == _STATISTICS:
                    self.statistics_messages = struct.unpack_from("<Q", body, 0)[0]
                elif opcode == _DATA_END:
                    in_summary = True
                elif opcode == _FOOTER:
                    self.has_summary = in_summary
                    break
            except (struct.error, UnicodeDecodeError, ValueError) as err:
                self._warn(
                    f"{self.path}: unreadable record (opcode 0x{opcode:02x}) at offset {pos}: {err}"
                )
            if opcode not in (_CHUNK, _MESSAGE_INDEX):
                last_chunk = None  # message indexes belong to the chunk right before them
            pos = end
        else:
            if not self.has_summary:
                self._warn(
                    f"{self.path}: no summary section (recording interrupted?); "
                    f"recovered {len(self.chunks)} chunk(s) up to offset {pos}"
                )
        self._resolve_channels()

    def _truncated(self, pos: int, what: str) -> None:
        self._warn(
            f"{self.path}: file ends inside {what} at offset {pos} "
            f"(recording interrupted?); read up to offset {pos}"
        )
        self.lost_unknown = True

    def _read_schema(self, body: memoryview) -> None:
        (schema_id,) = struct.unpack_from("<H", body, 0)
        pos = 2
        name, pos = _prefixed_str(body, pos)
        encoding, pos = _prefixed_str(body, pos)
        (dlen,) = struct.unpack_from("<I", body, pos)
        data = bytes(body[pos + 4 : pos + 4 + dlen])
        self._schemas.setdefault(schema_id, (name, encoding, data))

    def _read_channel(self, body: memoryview, offset: int = -1) -> None:
        channel_id, schema_id = struct.unpack_from("<HH", body, 0)
        topic, pos = _prefixed_str(body, 4)
        encoding, pos = _prefixed_str(body, pos)
        meta, _ = _string_map(body, pos)
        if channel_id not in self.channels:
            self._pending_channels.setdefault(
                channel_id, (topic, encoding, schema_id, meta, offset)
            )

    def _read_metadata(self, body: memoryview, offset: int = -1) -> None:
        name, pos = _prefixed_str(body, 0)
        data, _ = _string_map(body, pos)
        self.metadata.append((name, data))
        if name == "softbubble.channel" and data.get("channel_id", "").isdigit():
            channel_id = int(data["channel_id"])
            schema = TopicSchema.from_json(data.get("schema_data", ""), data.get("schema_name", ""))
            self.channels.setdefault(
                channel_id,
                ChannelInfo(
                    channel_id,
                    data.get("topic", ""),
                    schema,
                    data.get("message_encoding", ""),
                    offset,
                ),
            )

    def _resolve_channels(self) -> None:
        for channel_id, pending in list(self._pending_channels.items()):
            topic, encoding, schema_id, meta, offset = pending
            if channel_id in self.channels:
                continue
            name, _, data = self._schemas.get(schema_id, (meta.get("type", ""), "", b""))
            schema = TopicSchema.from_json(data, name)
            if not schema.fingerprint and "fingerprint" in meta:
                schema = TopicSchema(schema.type_name, meta["fingerprint"], schema.description)
            self.channels[channel_id] = ChannelInfo(channel_id, topic, schema, encoding, offset)
        self._pending_channels.clear()

    # -- metadata
    def _last_metadata(self, name: str) -> dict[str, str] | None:
        found = [data for n, data in self.metadata if n == name]
        return found[-1] if found else None

    def run_info(self) -> dict[str, Any]:
        """``graph_yaml``, ``graph_source``, ``command_line``, ``started_nanos``, ``host``, or ``{}``."""
        return dict(self._last_metadata("softbubble.run") or {})

    def drops(self) -> dict[str, dict[str, int]]:
        """The last ``softbubble.drops`` record: per topic runtime drops, seq gaps, rejected."""
        data = self._last_metadata("softbubble.drops")
        if data is None:
            return {}
        try:
            loaded = json.loads(data.get("drops", "{}"))
        except ValueError:
            self._warn(f"{self.path}: softbubble.drops metadata is not JSON")
            return {}
        return {str(t): {str(k): int(n) for k, n in d.items()} for t, d in loaded.items()}

    def topics(self) -> dict[str, TopicSchema]:
        """Every topic in the bag and its schema (the last channel's, if a topic has several)."""
        if not self.channels and self.chunks:
            # A foreign bag without a summary: channel records only live inside the chunks.
            for _ in self.messages():
                pass
        return {
            c.topic: c.schema for c in sorted(self.channels.values(), key=lambda c: c.channel_id)
        }

    def first_log_nanos(self) -> int | None:
        """The earliest ``log_time`` by the chunk headers (no decompression)."""
        starts = [c.start_nanos for c in self.chunks]
        for offset in self._loose_messages:
            starts.append(struct.unpack_from("<Q", self._view, offset + 9 + 6)[0])
        return min(starts) if starts else None

    def require_topics(self, topics: Iterable[str]) -> None:
        """Raise :class:`BagError` naming the file and topic for a topic not in the bag."""
        known = self.topics()
        for topic in topics:
            if topic not in known:
                raise BagError(
                    f"{self.path}: topic {topic!r} is not in the bag; it has: {', '.join(sorted(known))}"
                )

    # -- messages
    def _chunk_records(self, ref: _ChunkRef) -> memoryview | None:
        """The decompressed, CRC-checked records of a chunk; ``None`` (and a warning) if broken."""
        body = self._view[ref.offset + 9 : ref.offset + ref.length]
        try:
            start, stop, usize, crc, clen = struct.unpack_from("<QQQII", body, 0)
            compression = bytes(body[32 : 32 + clen]).decode()
            (rlen,) = struct.unpack_from("<Q", body, 32 + clen)
            data = body[40 + clen : 40 + clen + rlen]
            if data.nbytes != rlen:
                raise ValueError("records run past the chunk")
            records = _decompress(compression, data, usize)
            if len(records) != usize:
                raise ValueError(f"{len(records)} bytes after decompression, header says {usize}")
            if crc and zlib.crc32(records) != crc:
                raise ValueError("CRC mismatch")
            return memoryview(records)
        except Exception as err:  # noqa: BLE001 (zstd/lz4 raise their own types; all mean "broken")
            lost = sum(ref.index_counts.values())
            self.lost_messages += lost
            if not ref.index_counts:
                self.lost_unknown = True
            self._warn(
                f"{self.path}: corrupt chunk at offset {ref.offset} ({err}); skipped, "
                + (
                    f"{lost} message(s) lost"
                    if ref.index_counts
                    else "unknown number of messages lost"
                )
            )
            return None

    def messages(
        self,
        topics: Iterable[str] | None = None,
        *,
        start_nanos: int | None = None,
        end_nanos: int | None = None,
    ) -> Iterator[BagMessage]:
        """Every message in file order (the recorder's receive order), optionally filtered.

        ``start_nanos``/``end_nanos`` bound ``log_time`` (inclusive start, exclusive end).
        Corrupt chunks are skipped with a warning; see :attr:`lost_messages`.
        """
        wanted = set(topics) if topics is not None else None
        items: list[tuple[int, str, Any]] = [(c.offset, "chunk", c) for c in self.chunks]
        items += [(o, "message", o) for o in self._loose_messages]
        items.sort(key=lambda item: item[0])
        for offset, kind, ref in items:
            if kind == "message":
                (length,) = struct.unpack_from("<Q", self._view, offset + 1)
                body = self._view[offset + 9 : offset + 9 + length]
                msg = self._message(body, offset, wanted, start_nanos, end_nanos)
                if msg is not None:
                    yield msg
                continue
            if start_nanos is not None and ref.end_nanos < start_nanos:
                continue
            if end_nanos is not None and ref.start_nanos >= end_nanos:
                continue
            if (
                wanted is not None
                and ref.index_counts
                and set(ref.index_counts) <= set(self.channels)
            ):
                # Its message index says no wanted topic is inside: skip the decompression.
                if not any(self.channels[c].topic in wanted for c in ref.index_counts):
                    continue
            records = self._chunk_records(ref)
            if records is None:
                continue
            pos = 0
            while pos + 9 <= records.nbytes:
                opcode, length = struct.unpack_from("<BQ", records, pos)
                body = records[pos + 9 : pos + 9 + length]
                if body.nbytes != length:
                    self._warn(
                        f"{self.path}: chunk at offset {offset}: record at {pos} runs past the chunk"
                    )
                    break
                if opcode == _MESSAGE:
                    msg = self._message(body, offset, wanted, start_nanos, end_nanos, pos)
                    if msg is not None:
                        yield msg
                elif opcode == _SCHEMA:
                    self._read_schema(body)
                elif opcode == _CHANNEL:
                    self._read_channel(body)
                    self._resolve_channels()
                pos += 9 + length

    def _message(
        self,
        body: memoryview,
        offset: int,
        wanted: set[str] | None,
        start_nanos: int | None,
        end_nanos: int | None,
        chunk_pos: int = -1,
    ) -> BagMessage | None:
        if body.nbytes < 22:
            self.lost_messages += 1
            self._warn(f"{self.path}: message record at offset {offset} is too short; skipped")
            return None
        channel_id, seq, log_time, pub_time = struct.unpack_from("<HIQQ", body, 0)
        channel = self.channels.get(channel_id)
        if channel is None:
            self.lost_messages += 1
            self._warn(
                f"{self.path}: message at offset {offset} on unknown channel {channel_id}; skipped"
            )
            return None
        if wanted is not None and channel.topic not in wanted:
            return None
        if start_nanos is not None and log_time < start_nanos:
            return None
        if end_nanos is not None and log_time >= end_nanos:
            return None
        return BagMessage(
            channel.topic, channel, log_time, pub_time, seq, body[22:], offset, self.path, chunk_pos
        )

    def stats(self) -> dict[str, TopicStats]:
        """One full pass: per-topic counts, bytes, first/last log time, sequence gaps."""
        out: dict[str, TopicStats] = {}
        for m in self.messages():
            s = out.get(m.topic)
            if s is None:
                schema = m.channel.schema
                s = out[m.topic] = TopicStats(m.topic, schema.type_name, schema.fingerprint)
                s.first_log_nanos = m.log_time_nanos
            s.messages += 1
            s.bytes += m.payload.nbytes
            s.last_log_nanos = m.log_time_nanos
            if s.last_seq is not None and m.sequence > s.last_seq + 1:
                s.seq_gaps += m.sequence - s.last_seq - 1
            s.last_seq = m.sequence
        for channel in self.channels.values():
            if channel.topic not in out:
                out[channel.topic] = TopicStats(
                    channel.topic, channel.schema.type_name, channel.schema.fingerprint
                )
        return out


def _decompress(compression: str, data: memoryview, size: int) -> bytes | memoryview:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(bytes(data)))
    raise ValueError(f"unknown compression {compression!r}")


def _prefixed_str(buf: memoryview, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > buf.nbytes:
        raise ValueError("string runs past the record")
    return bytes(buf[pos + 4 : end]).decode(), end


def _string_map(buf: memoryview, pos: int) -> tuple[dict[str, str], int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    pos += 4
    out: dict[str, str] = {}
    while pos < end:
        key, pos = _prefixed_str(buf, pos)
        value, pos = _prefixed_str(buf, pos)
        out[key] = value
    return out, end


def topic_filter(pattern: str | None) -> Callable[[str], bool]:
    """A predicate for topics matching ``pattern`` (``re.search``, as ``launch.py --topics``
    selects what to record; anchor it with ``^...$`` for exact names; ``None`` = all).

    Raises:
        ValueError: the pattern is not a valid regular expression.
    """
    if not pattern:
        return lambda topic: True
    try:
        regex = re.compile(pattern)
    except re.error as err:
        raise ValueError(f"topics: bad regular expression {pattern!r}: {err}") from err
    return lambda topic: regex.search(topic) is not None
