"""Reading bags: every message, with or without today's classes, from whole or damaged files.

:class:`BagReader` maps the file and walks its top level once (:mod:`runtime.bag.scan`):
chunks, channels, schemas, metadata, the summary if there is one. It never needs the
summary, so a recording killed at any moment reads up to its last whole record; damage
is skipped with a warning naming the file and the byte offset (see ``scan``). Messages
come out in file order as :class:`BagMessage`, whose payload is a view on the map (or
on the decompressed chunk); every error is a :class:`messages.errors.BagError` naming
the file, the topic and the offset.
"""

from __future__ import annotations

import json
import logging
import mmap
import os
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import MAGIC_SIZE

from messages.errors import BagError
from runtime.bag.message import BagMessage
from runtime.bag.scan import ChunkRef, Scanner, Warn, chunk_records, walk_chunk
from runtime.bag.schema import ChannelInfo, TopicSchema
from runtime.bag.writer import TopicCounts

log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"


@dataclass(kw_only=True)
class TopicStats(TopicCounts):
    """Per-topic figures from a full pass over a bag."""

    topic: str
    type_name: str
    fingerprint: str
    first_log_nanos: int = 0
    last_log_nanos: int = 0

    @property
    def rate_hz(self) -> float:
        span = (self.last_log_nanos - self.first_log_nanos) / 1e9
        return (self.messages - 1) / span if self.messages > 1 and span > 0 else 0.0


class BagReader:
    """Reads a bag written by :class:`BagWriter` (or any MCAP file with a msgpack encoding).

    Opening walks the top level of the file once (no decompression). Problems are collected
    in :attr:`problems` and passed to ``warn`` (default: ``logging.warning``);
    :attr:`lost_messages` counts the messages of skipped chunks.
    """

    def __init__(self, path: str | Path, *, warn: Warn | None = None) -> None:
        self.path = Path(path)
        self._warn_fn = warn or (lambda text: log.warning("%s", text))
        self.problems: list[str] = []
        self.lost_messages = 0
        try:
            with open(self.path, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                if size < MAGIC_SIZE:
                    raise BagError(f"{self.path}: not an MCAP file ({size} bytes)")
                self._mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except OSError as err:
            raise BagError(f"{self.path}: cannot open: {err}") from err
        self._view = memoryview(self._mm)
        self.size = size
        if bytes(self._view[:MAGIC_SIZE]) != MAGIC:
            raise BagError(f"{self.path}: not an MCAP file (bad magic at offset 0)")
        self.channels: dict[int, ChannelInfo] = {}
        self._schemas: dict[int, Schema] = {}
        self._pending: dict[int, tuple[Channel, int]] = {}
        layout = Scanner(self.path, self._view, self._mm.find, self._warn).scan()
        self.chunks: list[ChunkRef] = layout.chunks
        self._loose = layout.loose
        self.has_summary = layout.has_summary
        self.lost_unknown = layout.lost_unknown
        self.statistics_messages = (
            layout.statistics.message_count if layout.statistics is not None else None
        )
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self._schemas.update(layout.schemas)
        for record, offset in layout.metadata:
            self._add_metadata(record.name, record.metadata, offset)
        for channel, offset in layout.channels:
            self._pending.setdefault(channel.id, (channel, offset))
        self._resolve_channels()

    def close(self) -> None:
        """Unmap the file (messages still referenced keep it mapped until they are freed)."""
        self.chunks = []  # these records hold views on the map
        self._loose = []
        self._schemas = {}
        try:
            self._view.release()
        except BufferError:
            return  # a view of it is still exported; the map goes with the last view
        # An array decoded by the codec holds the map object itself as its base (numpy
        # keeps the object, not a buffer export), so mmap.close() would not refuse and
        # would leave that array dangling. Close only when nothing but this reader (and
        # getrefcount's argument) refers to the map; else the last array unmaps it.
        if sys.getrefcount(self._mm) <= 2:
            try:
                self._mm.close()
            except BufferError:
                pass  # a BagMessage payload still points into the map

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _warn(self, text: str) -> None:
        self.problems.append(text)
        self._warn_fn(text)

    # -- channels and metadata
    def _add_metadata(self, name: str, data: dict[str, str], offset: int) -> None:
        self.metadata.append((name, data))
        if name == "softbubble.channel" and data.get("channel_id", "").isdigit():
            channel_id = int(data["channel_id"])
            schema = TopicSchema.from_json(
                data.get("schema_data", ""), data.get("schema_name", ""), data.get("packing", "")
            )
            if channel_id not in self.channels:
                self._add_channel(
                    ChannelInfo(
                        channel_id,
                        data.get("topic", ""),
                        schema,
                        data.get("message_encoding", ""),
                        offset,
                    )
                )

    def _add_channel(self, info: ChannelInfo) -> None:
        self.channels[info.channel_id] = info
        if info.schema.refused:
            self._warn(f"{self.path}: topic {info.topic}: {info.schema.refused}")

    def _resolve_channels(self) -> None:
        for channel_id, (channel, offset) in list(self._pending.items()):
            if channel_id in self.channels:
                continue
            meta = channel.metadata
            stored = self._schemas.get(channel.schema_id)
            name = stored.name if stored is not None else meta.get("type", "")
            data = bytes(stored.data) if stored is not None else b""
            schema = TopicSchema.from_json(data, name, meta.get("packing", ""))
            if not schema.fingerprint and "fingerprint" in meta:
                schema = TopicSchema(
                    schema.type_name, meta["fingerprint"], schema.description, schema.packing
                )
            self._add_channel(
                ChannelInfo(channel_id, channel.topic, schema, channel.message_encoding, offset)
            )
        self._pending.clear()

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
            return {str(t): {str(k): int(n) for k, n in d.items()} for t, d in loaded.items()}
        except (ValueError, TypeError, AttributeError):
            self._warn(f"{self.path}: softbubble.drops metadata is not a JSON table of counts")
            return {}

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
        starts = [c.start_nanos for c in self.chunks] + [m.log_time for _, m in self._loose]
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
    def _records(self, ref: ChunkRef) -> memoryview | None:
        """The decompressed, CRC-checked records of a chunk; ``None`` (and a warning) if broken."""
        try:
            return chunk_records(ref.chunk)
        except Exception as err:  # noqa: BLE001 (zstd/lz4 raise their own types; all mean "broken")
            self._lost(ref, err)
            return None

    def _lost(self, ref: ChunkRef, err: Exception) -> None:
        lost = sum(ref.index_counts.values())
        self.lost_messages += lost
        if not ref.index_counts:
            self.lost_unknown = True
        self._warn(
            f"{self.path}: corrupt chunk at offset {ref.offset} ({err}); skipped, "
            + (f"{lost} message(s) lost" if ref.index_counts else "unknown number of messages lost")
        )

    def _skip_chunk(
        self, ref: ChunkRef, wanted: set[str] | None, start: int | None, end: int | None
    ) -> bool:
        if start is not None and ref.end_nanos < start:
            return True
        if end is not None and ref.start_nanos >= end:
            return True
        if (
            wanted is None
            or not ref.index_counts
            or not set(ref.index_counts) <= set(self.channels)
        ):
            return False
        # Its message index says no wanted topic is inside: skip the decompression.
        return not any(self.channels[c].topic in wanted for c in ref.index_counts)

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
        items: list[tuple[int, ChunkRef | Message]] = [(c.offset, c) for c in self.chunks]
        items += self._loose
        items.sort(key=lambda item: item[0])
        for offset, item in items:
            if isinstance(item, Message):
                msg = self._message(item, offset, wanted, start_nanos, end_nanos)
                if msg is not None:
                    yield msg
                continue
            if self._skip_chunk(item, wanted, start_nanos, end_nanos):
                continue
            records = self._records(item)
            if records is None:
                continue
            try:
                for pos, record in walk_chunk(records):
                    if isinstance(record, Message):
                        msg = self._message(record, offset, wanted, start_nanos, end_nanos, pos)
                        if msg is not None:
                            yield msg
                    elif isinstance(record, Schema):
                        self._schemas.setdefault(record.id, record)
                    elif isinstance(record, Channel):
                        self._pending.setdefault(record.id, (record, -1))
                        self._resolve_channels()
            except ValueError as err:
                self._warn(
                    f"{self.path}: chunk at offset {offset}: {err}; rest of the chunk skipped"
                )
                self.lost_unknown = True

    def _message(
        self,
        record: Message,
        offset: int,
        wanted: set[str] | None,
        start_nanos: int | None,
        end_nanos: int | None,
        chunk_pos: int = -1,
    ) -> BagMessage | None:
        channel = self.channels.get(record.channel_id)
        if channel is None:
            self.lost_messages += 1
            self._warn(
                f"{self.path}: message at offset {offset} on unknown channel "
                f"{record.channel_id}; skipped"
            )
            return None
        if wanted is not None and channel.topic not in wanted:
            return None
        if start_nanos is not None and record.log_time < start_nanos:
            return None
        if end_nanos is not None and record.log_time >= end_nanos:
            return None
        return BagMessage(
            channel.topic,
            channel,
            record.log_time,
            record.publish_time,
            record.sequence,
            memoryview(record.data),
            offset,
            self.path,
            chunk_pos,
        )

    def stats(self) -> dict[str, TopicStats]:
        """One full pass: per-topic counts, bytes, first/last log time, sequence gaps."""
        out: dict[str, TopicStats] = {}
        for m in self.messages():
            s = out.get(m.topic)
            if s is None:
                schema = m.channel.schema
                s = out[m.topic] = TopicStats(
                    topic=m.topic, type_name=schema.type_name, fingerprint=schema.fingerprint
                )
                s.first_log_nanos = m.log_time_nanos
            s.messages += 1
            s.bytes += m.payload.nbytes
            s.last_log_nanos = m.log_time_nanos
            s.see(m.sequence)
        for channel in self.channels.values():
            if channel.topic not in out:
                out[channel.topic] = TopicStats(
                    topic=channel.topic,
                    type_name=channel.schema.type_name,
                    fingerprint=channel.schema.fingerprint,
                )
        return out
