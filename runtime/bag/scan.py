"""Walking an MCAP file record by record, and past the damage the ``mcap`` library stops at.

Records are parsed by the library (:mod:`mcap.records`, :class:`mcap.opcode.Opcode`,
:class:`mcap.data_stream.ReadDataStream`). What the library lacks, and this module adds:

- reading from a memory map without copying: :class:`ViewStream` hands the library
  views on the file (or on a decompressed chunk), so a message's arrays are never copied;
- going on after damage: a file cut short is read up to its last whole record; a chunk
  whose CRC or compression is broken is skipped and the messages its message index
  lists are counted as lost; a record whose framing is broken (unknown opcode, a length
  past the end) is skipped by resynchronising at the next readable chunk, found from the
  summary's chunk index when the file has an intact one, else by scanning for a record
  that parses as a whole chunk.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import MAGIC_SIZE

Warn = Callable[[str], None]

_RECORD_HEAD = 9  # opcode (1 byte) and record length (8 bytes)
_OPCODES = frozenset(int(op) for op in Opcode)
_COMPRESSIONS = ("", "zstd", "lz4")
# What a broken record's parse can raise: the library's errors, short reads, bad UTF-8.
PARSE_ERRORS = (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError)


class ViewStream:
    """A read-only file object over a memoryview whose reads are views (no copy)."""

    def __init__(self, view: memoryview) -> None:
        self._view = view
        self._pos = 0

    def read(self, size: int = -1) -> memoryview:
        if size < 0:
            raise ValueError(f"negative read of {size} bytes (a corrupt length)")
        out = self._view[self._pos : self._pos + size]
        self._pos += out.nbytes
        return out


def stream_on(view: memoryview) -> ReadDataStream:
    return ReadDataStream(ViewStream(view))  # type: ignore[arg-type]


_PARSERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.CHUNK: Chunk.read,
    Opcode.MESSAGE_INDEX: MessageIndex.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.METADATA: Metadata.read,
    Opcode.STATISTICS: Statistics.read,
    Opcode.DATA_END: DataEnd.read,
    Opcode.FOOTER: Footer.read,
}


def read_record(opcode: int, stream: ReadDataStream, length: int) -> McapRecord | None:
    """The library's record for ``opcode`` (``None`` for records a bag reader has no use for)."""
    if opcode == Opcode.MESSAGE:
        message: Message = Message.read(stream, length)
        return message
    parse = _PARSERS.get(opcode)
    return None if parse is None else parse(stream)


@dataclass
class ChunkRef:
    """A chunk at the top level; ``chunk.data`` is a view on the file."""

    offset: int
    length: int  # of the whole record, opcode and length field included
    chunk: Chunk
    index_counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages

    @property
    def start_nanos(self) -> int:
        return self.chunk.message_start_time

    @property
    def end_nanos(self) -> int:
        return self.chunk.message_end_time


@dataclass
class Layout:
    """What one walk of the top level found (no chunk decompressed)."""

    chunks: list[ChunkRef] = field(default_factory=list)
    loose: list[tuple[int, Message]] = field(default_factory=list)  # messages outside chunks
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: list[tuple[Channel, int]] = field(default_factory=list)  # and their offsets
    metadata: list[tuple[Metadata, int]] = field(default_factory=list)
    statistics: Statistics | None = None
    has_summary: bool = False
    lost_unknown: bool = False  # something was skipped whose message count is unknown


def summary_chunk_offsets(path: Path) -> list[int] | None:
    """Chunk offsets from the summary's chunk indexes (``None``: no intact summary)."""
    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except (*PARSE_ERRORS, OSError, MemoryError):
        return None
    if summary is None:
        return None
    return sorted(index.chunk_start_offset for index in summary.chunk_indexes)


def _whole_chunk(view: memoryview, pos: int) -> bool:
    """Whether a record that parses as a complete, plausible chunk starts at ``pos``."""
    head = stream_on(view[pos : pos + _RECORD_HEAD])
    try:
        if head.read1() != Opcode.CHUNK:
            return False
        length = head.read8()
        if pos + _RECORD_HEAD + length > view.nbytes:
            return False
        stream = stream_on(view[pos + _RECORD_HEAD : pos + _RECORD_HEAD + length])
        chunk = Chunk.read(stream)
    except PARSE_ERRORS:
        return False
    return (
        stream.count == length
        and chunk.compression in _COMPRESSIONS
        and chunk.uncompressed_size < 1 << 34
    )


class Scanner:
    """Walks the top level of a mapped MCAP file once; see the module docstring."""

    def __init__(self, path: Path, view: memoryview, find: Callable[[bytes, int], int], warn: Warn):
        self.path = path
        self.view = view
        self.size = view.nbytes
        self._find = find  # the map's find(), to look for the next chunk's opcode
        self.warn = warn
        self._summary_offsets: list[int] | None | bool = False  # False: not looked up yet

    def _resync(self, pos: int) -> int | None:
        """The offset of the next readable chunk after a broken record at ``pos``."""
        if self._summary_offsets is False:
            self._summary_offsets = summary_chunk_offsets(self.path)
        if isinstance(self._summary_offsets, list):
            later = [o for o in self._summary_offsets if o > pos]
            return min(later) if later else None
        probe = pos + 1
        while True:
            probe = self._find(bytes([Opcode.CHUNK]), probe)
            if probe < 0:
                return None
            if _whole_chunk(self.view, probe):
                return probe
            probe += 1

    def scan(self) -> Layout:
        out = Layout()
        pos = MAGIC_SIZE
        last_chunk: ChunkRef | None = None
        in_summary = False
        while pos < self.size:
            if pos + _RECORD_HEAD > self.size:
                self._truncated(out, pos, "a record header")
                break
            head = stream_on(self.view[pos : pos + _RECORD_HEAD])
            opcode, length = head.read1(), head.read8()
            end = pos + _RECORD_HEAD + length
            if opcode not in _OPCODES or end > self.size:
                if end > self.size and opcode in _OPCODES and self._no_summary():
                    self._truncated(out, pos, f"a record (opcode 0x{opcode:02x}) of {length} bytes")
                    break
                nxt = self._resync(pos)
                self.warn(
                    f"{self.path}: broken record at offset {pos} (opcode 0x{opcode:02x}, "
                    f"length {length}); "
                    + (f"resuming at offset {nxt}" if nxt else "nothing readable after it")
                )
                out.lost_unknown = True
                if nxt is None:
                    break
                pos = nxt
                continue
            try:
                record = read_record(opcode, stream_on(self.view[pos + _RECORD_HEAD : end]), length)
            except PARSE_ERRORS as err:
                self.warn(
                    f"{self.path}: unreadable record (opcode 0x{opcode:02x}) at offset {pos}: {err}"
                )
                record = None
            if isinstance(record, Chunk):
                last_chunk = ChunkRef(pos, end - pos, record)
                out.chunks.append(last_chunk)
            elif isinstance(record, MessageIndex) and last_chunk is not None:
                last_chunk.index_counts[record.channel_id] = len(record.records)
            elif isinstance(record, Message):
                out.loose.append((pos, record))
            elif isinstance(record, Schema):
                out.schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                out.channels.append((record, pos))
            elif isinstance(record, Metadata):
                out.metadata.append((record, pos))
            elif isinstance(record, Statistics):
                out.statistics = record
            elif isinstance(record, DataEnd):
                in_summary = True
            elif isinstance(record, Footer):
                out.has_summary = in_summary
                break
            if not isinstance(record, Chunk | MessageIndex):
                last_chunk = None  # message indexes belong to the chunk right before them
            pos = end
        else:
            if not out.has_summary:
                self.warn(
                    f"{self.path}: no summary section (recording interrupted?); "
                    f"recovered {len(out.chunks)} chunk(s) up to offset {pos}"
                )
        return out

    def _no_summary(self) -> bool:
        if self._summary_offsets is False:
            self._summary_offsets = summary_chunk_offsets(self.path)
        return self._summary_offsets is None

    def _truncated(self, out: Layout, pos: int, what: str) -> None:
        self.warn(
            f"{self.path}: file ends inside {what} at offset {pos} "
            f"(recording interrupted?); read up to offset {pos}"
        )
        out.lost_unknown = True


def _decompress(chunk: Chunk) -> memoryview:
    data = memoryview(chunk.data)
    if chunk.compression == "":
        return data
    if chunk.compression == "zstd":
        import zstandard

        return memoryview(
            zstandard.ZstdDecompressor().decompress(data, max_output_size=chunk.uncompressed_size)
        )
    if chunk.compression == "lz4":
        import lz4.frame

        return memoryview(lz4.frame.decompress(bytes(data)))
    raise ValueError(f"unknown compression {chunk.compression!r}")


def chunk_records(chunk: Chunk) -> memoryview:
    """The chunk's records, decompressed and CRC-checked.

    Raises:
        Exception: any failure of decompression (zstd and lz4 raise their own types), a size
            or CRC mismatch (``ValueError``): the chunk is broken.
    """
    records = _decompress(chunk)
    if records.nbytes != chunk.uncompressed_size:
        raise ValueError(
            f"{records.nbytes} bytes after decompression, header says {chunk.uncompressed_size}"
        )
    if chunk.uncompressed_crc and zlib.crc32(records) != chunk.uncompressed_crc:
        raise ValueError("CRC mismatch")
    return records


def walk_chunk(records: memoryview) -> Iterator[tuple[int, McapRecord | None]]:
    """``(position, record)`` for each record of a decompressed chunk, by the library.

    Raises:
        ValueError: a record runs past the chunk, or does not parse.
    """
    pos = 0
    while pos + _RECORD_HEAD <= records.nbytes:
        head = stream_on(records[pos : pos + _RECORD_HEAD])
        opcode, length = head.read1(), head.read8()
        end = pos + _RECORD_HEAD + length
        if end > records.nbytes:
            raise ValueError(f"record at {pos} runs past the chunk")
        try:
            record = read_record(opcode, stream_on(records[pos + _RECORD_HEAD : end]), length)
        except PARSE_ERRORS as err:
            raise ValueError(f"record at {pos} does not parse: {err}") from err
        yield pos, record
        pos = end
