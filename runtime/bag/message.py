"""One recorded message as the reader gives it (and the writer copies it to another bag)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from messages.base import Message as TypedMessage
from messages.codec import decode
from messages.errors import BagError, FrameDecodeError
from runtime.bag.packing import unpack
from runtime.bag.schema import ChannelInfo


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

    def frames(self) -> list[Any]:
        """``[header, *buffers]`` as on the wire (no topic frame); buffers are views.

        Raises:
            BagError: the message cannot be unpacked, or its channel's schema was refused
                (its text does not match its fingerprint).
        """
        refused = self.channel.schema.refused
        if refused:
            raise BagError(f"{self.where()}: {refused}")
        try:
            return unpack(self.payload, self.channel.schema.packing)
        except FrameDecodeError as err:
            raise BagError(f"{self.where()}: {err}") from err

    def wire_frames(self, topic: str | None = None) -> list[Any]:
        """The full multipart message ``[topic, header, *buffers]``, ready to publish."""
        return [(topic or self.topic).encode(), *self.frames()]

    def header(self) -> dict[str, Any]:
        """The wire header (type, fp, fields, arrays) decoded with the plain ``msgpack`` package."""
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
        wrong = self.channel.schema.field_mismatch(fields)
        if wrong is not None:
            raise BagError(f"{self.where()}: {wrong}")
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

    def decode(self) -> TypedMessage:
        """Decode into today's message class.

        A message recorded under an older declaration of its type decodes when today's
        only adds fields with defaults (filled in; ``messages.evolution``).

        Raises:
            BagError: the type is unknown today or changed otherwise since the recording
                (the message names the type and the field; use :meth:`decode_plain`), or
                the message is malformed.
        """
        try:
            return decode(self.wire_frames(), stored=self.channel.schema.description)[1]
        except FrameDecodeError as err:
            raise BagError(f"{self.where()}: {err}") from err
