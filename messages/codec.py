"""Message <-> multipart ZeroMQ frames.

Wire format (one message = one multipart ZeroMQ message)::

    frame 0   topic, UTF-8 ("node/output")
    frame 1   MessagePack map:
                {"type": "ToFImage", "fp": "<16 hex>",
                 "fields": {<every non-array field, nested structs as maps>},
                 "arrays": [[name, dtype.str, [shape...]], ...]}
    frame 2+  one raw, C-contiguous little-endian buffer per array, in "arrays" order

Frame 1 decodes with the plain ``msgpack`` package, so peers in other languages can
join. Arrays are sent from their own memory (no copy when already contiguous and
little-endian) and received as read-only views on the ZeroMQ frames' buffers.
Every way a frame can be wrong raises :class:`FrameDecodeError` (or its subclass
:class:`FingerprintMismatchError`); nothing else escapes :func:`decode`.

Bags store the same content as ONE MessagePack value per message (:func:`pack_single`,
:func:`unpack_single`, at the end of this module), so any MessagePack library reads a
recorded message whole; the live wire stays multipart and zero-copy.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from messages.base import Array, Message
from messages.errors import FingerprintMismatchError, FrameDecodeError, SchemaChangeError
from messages.evolution import check_stored

_encoder = msgspec.msgpack.Encoder()
_header_decoder = msgspec.msgpack.Decoder()


_ArrayRows = list[tuple[str, str, list[int]]]


class WireHeader(msgspec.Struct, forbid_unknown_fields=True):
    """The envelope of frame 1, validated on decode."""

    type: str
    fp: str
    fields: dict[str, Any]
    arrays: _ArrayRows


_wire_decoder = msgspec.msgpack.Decoder(WireHeader)
_rows_decoder = msgspec.msgpack.Decoder(_ArrayRows)


class _Envelope(msgspec.Struct, forbid_unknown_fields=True):
    """Frame 1 with its array rows kept as undecoded MessagePack: the key to a layout
    already checked (see :func:`decode`)."""

    type: str
    fp: str
    fields: dict[str, Any]
    arrays: msgspec.Raw


_envelope_decoder = msgspec.msgpack.Decoder(_Envelope)


# One array of a received header, checked against its declaration: name, dtype as the
# sender spelled it (for the error messages), dtype, shape, and the bytes its buffer must
# hold. A plain tuple: made once per layout, unpacked once per array of every frame.
_Row = tuple[str, str, np.dtype[Any], tuple[int, ...], int]
# Layouts remembered per message class (see decode): a sender of ever new shapes empties
# its class's table each time it is full, and is checked in full every time.
_LAYOUTS_MAX = 64


@dataclass(frozen=True, slots=True)
class _WireArray:
    """One array field as the wire carries it: its declaration and little-endian dtype."""

    name: str
    spec: Array
    dtype: np.dtype[Any]
    dtype_str: str  # how the encoder spells it: the usual spelling on the wire
    fixed_axes: tuple[tuple[int, int], ...]
    ndim: int
    shape: tuple[int, ...] | None  # the declared shape where it fixes every axis

    def fits(self, shape: Sequence[int]) -> bool:
        """Whether ``shape`` has the declared number of axes and every fixed axis length."""
        if len(shape) != len(self.spec.shape):
            return False
        # A loop, not all(...): most declarations fix no axis, and a generator costs more.
        for axis, length in self.fixed_axes:
            if shape[axis] != length:
                return False
        return True


@dataclass(frozen=True, slots=True)
class _Plan:
    """What encode and decode need of a message class, computed once per class."""

    type_name: str
    fingerprint: str
    arrays: tuple[_WireArray, ...]
    arrays_by_name: dict[str, _WireArray]
    scalar_names: tuple[str, ...]
    # The header's array rows as sent -> those rows checked, for today's fingerprint: a
    # stream sends the same rows in every frame, so decode checks them once.
    layouts: dict[bytes, tuple[_Row, ...]]


@functools.cache
def _plan(cls: type[Message]) -> _Plan:
    schema = cls.schema()
    arrays = []
    for name, spec in schema.array_fields.items():
        # Through .str: the interned dtype that freshly made arrays carry, so the encoder's
        # identity test hits.
        dtype = np.dtype(np.dtype(spec.dtype).newbyteorder("<").str)
        fixed = tuple((axis, n) for axis, n in enumerate(spec.shape) if n is not None)
        full = tuple(n for n in spec.shape if n is not None)
        shape = full if len(full) == len(spec.shape) else None
        arrays.append(_WireArray(name, spec, dtype, dtype.str, fixed, len(spec.shape), shape))
    return _Plan(
        type_name=cls.__name__,
        fingerprint=schema.fingerprint,
        arrays=tuple(arrays),
        arrays_by_name={a.name: a for a in arrays},
        scalar_names=tuple(
            f.name for f in msgspec.structs.fields(cls) if f.name not in schema.array_fields
        ),
        layouts={},
    )


def _wire_array(msg: Message, field: _WireArray, value: Any) -> np.ndarray:
    """``value`` of ``msg``'s array ``field``, made C-contiguous and little-endian, after
    the declaration's full check (raises ``ValueError``): what :func:`encode` does with an
    array that is not already one it can send as it is."""
    field.spec.check(type(msg).__name__, field.name, value)
    array = np.asarray(value)
    if array.dtype != field.dtype:
        array = array.astype(field.dtype)  # the same values, byte-swapped
    # np.ascontiguousarray would turn a 0-d array into shape (1,).
    return array if array.flags.c_contiguous else np.ascontiguousarray(array)


def _numpy_scalar(obj: Any) -> Any:
    """Numpy scalars (what reductions like ``depth.mean()`` return) travel as Python values."""
    if isinstance(obj, np.generic) and obj.dtype.kind in "biufU":
        return obj.item()
    raise NotImplementedError(f"cannot encode {type(obj).__name__}")


# Frame 1's encoder: nested structs (the Header) are written as maps straight from the
# message, the same bytes as converting them to dicts first, without the dicts.
_header_encoder = msgspec.msgpack.Encoder(enc_hook=_numpy_scalar)


def _unencodable(fields: dict[str, Any]) -> str:
    """The first field that does not encode (only called once encoding has failed)."""
    for name, value in fields.items():
        try:
            _header_encoder.encode(value)
        except (TypeError, OverflowError, NotImplementedError):
            return name
    return "?"


def encode(topic: str, msg: Message) -> list[Any]:
    """Encode ``msg`` as multipart frames ``[topic, header, *buffers]``.

    Raises:
        ValueError: an array field does not match its declaration, or a field holds a
            value MessagePack cannot carry (an int past 64 bits, an arbitrary object);
            the message names the field.
    """
    plan = _plan(type(msg))
    rows = []
    frames: list[Any] = [topic.encode(), b""]
    # Every field in one C call; the arrays are taken out of it as the loop reaches them,
    # which leaves the fields of frame 1 in declaration order.
    fields = msgspec.structs.asdict(msg)
    take = fields.pop
    # One loop, no call per array in the usual case: this runs for every frame a node
    # publishes (docs/transport.md, "The hot path").
    for field in plan.arrays:
        array = take(field.name)
        # The buffer's own layout (no flags object), and the memoryview is what pyzmq
        # sends (any C-contiguous buffer) without copying.
        view = array.data if type(array) is np.ndarray and array.dtype is field.dtype else None
        # A declaration that fixes every axis (a 4 x 4 pose) is one tuple comparison, not a
        # call of fits (0.2 us).
        if view is None or not (
            view.c_contiguous
            and (
                array.shape == field.shape
                or field.shape is None
                and len(array.shape) == field.ndim
                and (not field.fixed_axes or field.fits(array.shape))
            )
        ):
            array = _wire_array(msg, field, array)
            view = array.data
        # A tuple shape packs as the same MessagePack array as a list.
        rows.append((field.name, field.dtype_str, array.shape))
        # A zero-length axis has no bytes: pyzmq is given an empty bytes for it.
        frames.append(view if view.nbytes else b"")
    try:
        frames[1] = _header_encoder.encode(
            {"type": plan.type_name, "fp": plan.fingerprint, "fields": fields, "arrays": rows}
        )
    except (TypeError, OverflowError, NotImplementedError) as err:
        raise ValueError(f"{type(msg).__name__}.{_unencodable(fields)}: {err}") from err
    return frames


# What msgspec raises for a frame 1 it cannot take (RecursionError: a header nested deeper
# than msgspec's recursion limit; UnicodeDecodeError: invalid UTF-8 in a str).
_HEADER_ERRORS = (
    msgspec.DecodeError,
    msgspec.ValidationError,
    UnicodeDecodeError,
    ValueError,
    RecursionError,
)


def decode_header(raw: bytes | memoryview) -> WireHeader:
    """Decode and validate frame 1 alone (cheap: no array is touched)."""
    try:
        return _wire_decoder.decode(raw)
    except _HEADER_ERRORS as err:
        raise FrameDecodeError(f"bad frame header: {err}") from err


def _buffer(frame: Any) -> memoryview:
    buf = getattr(frame, "buffer", frame)  # a zmq.Frame's is a memoryview already
    return buf if type(buf) is memoryview else memoryview(buf)


def _passthrough(kind: type, obj: Any) -> Any:
    if kind is np.ndarray and isinstance(obj, np.ndarray):
        return obj
    raise NotImplementedError(f"cannot convert {type(obj).__name__} to {kind}")


def _layout(topic: str, wire_type: str, arrays: _ArrayRows, plan: _Plan) -> tuple[_Row, ...]:
    """Each header row checked against its declaration: a known array field, the declared
    dtype, a shape that fits (raises ``FrameDecodeError``); no buffer is looked at."""
    rows = []
    for name, dtype_str, shape in arrays:
        field = plan.arrays_by_name.get(name)
        if field is None:
            raise FrameDecodeError(f"{topic}: {wire_type} has no array field {name!r}")
        dtype = field.dtype  # the usual spelling: numpy's parser would return an equal dtype
        if dtype_str != field.dtype_str:
            dtype = _wire_dtype(topic, wire_type, name, dtype_str, field)
        # The shape is checked before numpy sees it: no array is built for a frame refused.
        if (
            len(shape) != field.ndim
            or (field.fixed_axes and not field.fits(shape))
            or (shape and min(shape) < 0)
        ):
            raise FrameDecodeError(
                f"{topic}: {wire_type}.{name}: shape {shape}, declared {list(field.spec.shape)}"
            )
        # Python ints: no wrap-around.
        rows.append((name, dtype_str, dtype, tuple(shape), math.prod(shape) * dtype.itemsize))
    return tuple(rows)


def _received_arrays(
    topic: str, wire_type: str, fields: dict[str, Any], rows: tuple[_Row, ...], frames: Any
) -> dict[str, Any]:
    """``fields`` (decoded for this call alone: filled in place) with each checked row's
    array added, a read-only view on its frame, ``frames[2:]`` in order (the caller has
    checked that there is one per row; raises ``FrameDecodeError`` for a buffer of
    another size). One loop for every array of a message: this runs for each frame a
    node receives, and a call per array costs more than its checks."""
    i = 2
    for name, dtype_str, dtype, shape, nbytes in rows:
        # zmq.Frame buffers are writable, and over inproc they can be the sender's own
        # array: a receiver must never write through to it. numpy makes arrays on a
        # read-only view read-only (cheaper than clearing the flag afterwards).
        buf = memoryview(frames[i]).toreadonly()  # a zmq.Frame's own buffer, as bytes' are
        i += 1
        if buf.nbytes != nbytes:
            raise FrameDecodeError(
                f"{topic}: {wire_type}.{name}: buffer of {buf.nbytes} bytes, shape "
                f"{list(shape)} of {dtype_str} needs {nbytes}"
            )
        try:
            # Positional: numpy parses keyword arguments to ndarray() on a slower path
            # (about 0.6 us an array on frames fresh off the socket).
            fields[name] = np.ndarray(shape, dtype, buf)
        except ValueError as err:  # an axis past numpy's limit (with another axis of 0)
            raise FrameDecodeError(
                f"{topic}: {wire_type}.{name}: bad shape {list(shape)}: {err}"
            ) from err
    return fields


def _wire_dtype(
    topic: str, wire_type: str, name: str, dtype_str: str, field: _WireArray
) -> np.dtype[Any]:
    """A dtype spelled otherwise than the encoder spells it, if it is the declared one."""
    try:
        dtype = np.dtype(dtype_str)
    except (TypeError, ValueError, SyntaxError) as err:  # numpy's dtype-string parser
        raise FrameDecodeError(f"{topic}: {wire_type}.{name}: bad dtype {dtype_str!r}") from err
    # The wire carries little-endian buffers only ("=f4" and "f4" mean "<f4" here): a
    # big-endian array would reach the node and trip torch.from_numpy and OpenCV.
    if dtype.hasobject or dtype != field.dtype:
        raise FrameDecodeError(
            f"{topic}: {wire_type}.{name}: dtype {dtype_str!r}, declared {field.spec.dtype}"
        )
    return dtype


def decode(
    frames: Sequence[Any],
    expect: type[Message] | None = None,
    *,
    stored: dict[str, Any] | None = None,
    topic: str | None = None,
) -> tuple[str, Message]:
    """Decode ``[topic, header, *buffers]`` (bytes or ``zmq.Frame``) into ``(topic, message)``.

    Args:
        frames: the multipart message as received.
        expect: if given, the frame must carry this type (and its fingerprint).
        stored: the description of the frame's type as it was declared when the frame was
            recorded (a bag stores it). A frame of another fingerprint then decodes if
            that declaration evolves into today's (``messages.evolution``: fields added
            with defaults are filled in); without it, another fingerprint is refused.
        topic: frame 0 as text, where the caller has read it already (a node's runner
            has matched it to an input's topic): not read again.

    Raises:
        FrameDecodeError: truncated, wrong buffer size, unknown type, bad dtype or fields.
        FingerprintMismatchError: same type name, different schema (``SchemaChangeError``
            when a stored description was given: it names the field).
    """
    if len(frames) < 2:
        raise FrameDecodeError(f"truncated message: {len(frames)} frame(s), need at least 2")
    if topic is None:
        try:
            topic = str(getattr(frames[0], "bytes", frames[0]), "utf-8")  # zmq.Frame or bytes
        except UnicodeDecodeError as err:
            raise FrameDecodeError("topic frame is not UTF-8") from err
    # msgspec reads any buffer, a zmq.Frame's too: no memoryview made for it here.
    head = frames[1]
    # Frame 1 with its array rows undecoded: rows that are, byte for byte, those of a frame
    # of the same type already checked need no check again, only the fields, the buffers
    # and the frame count do (1.8 us less a ToFImage). A header the envelope or the rows do
    # not take is read again whole, for the error it gets there.
    try:
        envelope = _envelope_decoder.decode(head)
    except _HEADER_ERRORS as err:
        decode_header(head)  # refuses it, with the error of the whole header's reading
        raise FrameDecodeError(f"bad frame header: {err}") from err
    key = bytes(envelope.arrays)
    cls = Message.registry.get(envelope.type)
    if cls is not None:
        plan = _plan(cls)
        rows = plan.layouts.get(key)
        if rows is not None and envelope.fp == plan.fingerprint:
            return topic, _message(topic, cls, expect, envelope.fields, rows, frames)
    try:
        arrays = _rows_decoder.decode(key)
    except _HEADER_ERRORS as err:
        decode_header(head)
        raise FrameDecodeError(f"bad frame header: {err}") from err
    if cls is None:
        raise FrameDecodeError(f"{topic}: unknown message type {envelope.type!r}")
    if expect is not None and cls is not expect:
        raise FrameDecodeError(f"{topic}: expected {expect.__name__}, got {envelope.type}")
    plan = _plan(cls)
    if envelope.fp != plan.fingerprint and stored is not None:
        try:
            check_stored(cls, envelope.fp, stored)
        except SchemaChangeError as err:
            raise SchemaChangeError(f"{topic}: {err}") from None
    elif envelope.fp != plan.fingerprint:
        raise FingerprintMismatchError(
            f"{topic}: {envelope.type} fingerprint {envelope.fp} from the sender, "
            f"{plan.fingerprint} here: the two sides declare different fields"
        )
    rows = _layout(topic, envelope.type, arrays, plan)
    msg = _message(topic, cls, expect, envelope.fields, rows, frames)
    if envelope.fp == plan.fingerprint:
        if len(plan.layouts) >= _LAYOUTS_MAX:
            plan.layouts.clear()
        plan.layouts[key] = rows
    return topic, msg


def _message(
    topic: str,
    cls: type[Message],
    expect: type[Message] | None,
    fields: dict[str, Any],
    rows: tuple[_Row, ...],
    frames: Sequence[Any],
) -> Message:
    """The message of ``fields`` and the arrays of ``rows`` (checked) on ``frames[2:]``."""
    if expect is not None and cls is not expect:
        raise FrameDecodeError(f"{topic}: expected {expect.__name__}, got {cls.__name__}")
    if len(frames) != 2 + len(rows):
        raise FrameDecodeError(
            f"{topic}: {cls.__name__} header lists {len(rows)} arrays, got {len(frames) - 2} buffers"
        )
    fields = _received_arrays(topic, cls.__name__, fields, rows, frames)
    try:
        return msgspec.convert(fields, cls, dec_hook=_passthrough)
    except (msgspec.ValidationError, NotImplementedError, TypeError) as err:
        raise FrameDecodeError(f"{topic}: {cls.__name__}: {err}") from err


# -- the single-value form (bags) ----------------------------------------------------------------
#
# A bag stores each message as ONE MessagePack map, so that any MessagePack library reads it
# whole (docs/bags.md):
#
#     {"type": "ToFImage", "fp": "<16 hex>",
#      "fields": {<as in frame 1>},
#      "arrays": {"depth_m": {"dtype": "<f4", "shape": [172, 224], "order": "C",
#                             "data": <bin: the raw buffer>}, ...}}
#
# It holds exactly what the multipart frames hold; the two convert without touching the
# fields (kept as raw MessagePack) or copying the arrays on the way back.


class _RawHeader(msgspec.Struct, forbid_unknown_fields=True):
    """Frame 1 with its ``fields`` kept as undecoded MessagePack (same keys, same order)."""

    type: str
    fp: str
    fields: msgspec.Raw
    arrays: list[tuple[str, str, list[int]]]


class _StoredArray(msgspec.Struct, forbid_unknown_fields=True):
    dtype: str
    shape: list[int]
    order: str
    data: memoryview  # decoded as a view on the stored value: no copy


class _Stored(msgspec.Struct, forbid_unknown_fields=True):
    type: str
    fp: str
    fields: msgspec.Raw
    arrays: dict[str, _StoredArray]


_raw_header_decoder = msgspec.msgpack.Decoder(_RawHeader)
_stored_decoder = msgspec.msgpack.Decoder(_Stored)


def _check_buffers(
    wire_type: str, rows: Sequence[tuple[str, str, list[int]]], buffers: Sequence[memoryview]
) -> None:
    """Each buffer holds exactly its row's shape of its dtype (raises ``FrameDecodeError``)."""
    if len(buffers) != len(rows):
        raise FrameDecodeError(f"{wire_type}: header lists {len(rows)} arrays, got {len(buffers)}")
    if len({name for name, _, _ in rows}) != len(rows):
        raise FrameDecodeError(f"{wire_type}: an array name appears twice")
    for (name, dtype_str, shape), buf in zip(rows, buffers, strict=True):
        try:
            dtype = np.dtype(dtype_str)
        except (TypeError, ValueError, SyntaxError) as err:
            raise FrameDecodeError(f"{wire_type}.{name}: bad dtype {dtype_str!r}") from err
        if dtype.hasobject or min(shape, default=0) < 0:
            raise FrameDecodeError(f"{wire_type}.{name}: dtype {dtype_str!r} shape {shape}")
        want = math.prod(shape) * dtype.itemsize
        if buf.nbytes != want:
            raise FrameDecodeError(
                f"{wire_type}.{name}: buffer of {buf.nbytes} bytes, "
                f"shape {shape} of {dtype_str} needs {want}"
            )


def _flat(frame: Any) -> memoryview:
    view = _buffer(frame)
    return view if view.format == "B" and view.ndim == 1 else view.cast("B")


def pack_single(frames: Sequence[Any]) -> bytes:
    """``[header, *buffers]`` (the multipart frames without the topic) as one MessagePack value.

    Raises:
        FrameDecodeError: the header does not decode, or the buffers do not match it.
    """
    try:
        head = _raw_header_decoder.decode(_buffer(frames[0]))
    except (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError, ValueError) as err:
        raise FrameDecodeError(f"bad frame header: {err}") from err
    buffers = [_flat(f) for f in frames[1:]]
    _check_buffers(head.type, head.arrays, buffers)
    arrays = {
        name: _StoredArray(dtype, shape, "C", buf)
        for (name, dtype, shape), buf in zip(head.arrays, buffers, strict=True)
    }
    return _encoder.encode(_Stored(head.type, head.fp, head.fields, arrays))


def unpack_single(data: bytes | memoryview) -> list[Any]:
    """One stored MessagePack value back to ``[header, *buffers]`` (buffers are views on ``data``).

    Raises:
        FrameDecodeError: not such a value, an array not in C order, or a buffer that does
            not match its dtype and shape.
    """
    try:
        stored = _stored_decoder.decode(data)
    except (
        msgspec.DecodeError,
        msgspec.ValidationError,
        UnicodeDecodeError,
        ValueError,
        RecursionError,
    ) as err:
        raise FrameDecodeError(f"not a stored message: {err}") from err
    rows = []
    for name, array in stored.arrays.items():
        if array.order != "C":
            raise FrameDecodeError(f"{stored.type}.{name}: order {array.order!r}, expected 'C'")
        rows.append((name, array.dtype, array.shape))
    buffers = [a.data for a in stored.arrays.values()]
    _check_buffers(stored.type, rows, buffers)
    header = _encoder.encode(_RawHeader(stored.type, stored.fp, stored.fields, rows))
    return [header, *buffers]
