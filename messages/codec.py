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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import msgspec
import numpy as np

from messages.base import Message
from messages.errors import FingerprintMismatchError, FrameDecodeError

_encoder = msgspec.msgpack.Encoder()
_header_decoder = msgspec.msgpack.Decoder()


class WireHeader(msgspec.Struct, forbid_unknown_fields=True):
    """The envelope of frame 1, validated on decode."""

    type: str
    fp: str
    fields: dict[str, Any]
    arrays: list[tuple[str, str, list[int]]]


_wire_decoder = msgspec.msgpack.Decoder(WireHeader)


def _wire_array(msg: Message, name: str) -> np.ndarray:
    value = getattr(msg, name)
    spec = msg.schema().array_fields[name]
    array = np.asarray(value)
    want = np.dtype(spec.dtype).newbyteorder("<")
    if array.dtype != want:
        if array.dtype.newbyteorder("=") != want.newbyteorder("="):
            raise ValueError(
                f"{type(msg).__name__}.{name}: dtype must be {spec.dtype}, got {array.dtype}"
            )
        array = array.astype(want)
    # np.ascontiguousarray would turn a 0-d array into shape (1,).
    return array if array.flags.c_contiguous else np.ascontiguousarray(array)


def _numpy_scalar(obj: Any) -> Any:
    """Numpy scalars (what reductions like ``depth.mean()`` return) travel as Python values."""
    if isinstance(obj, np.generic) and obj.dtype.kind in "biufU":
        return obj.item()
    raise NotImplementedError(f"cannot encode {type(obj).__name__}")


def _unencodable(fields: dict[str, Any]) -> str:
    """The first field that does not encode (only called once encoding has failed)."""
    for name, value in fields.items():
        try:
            _encoder.encode(msgspec.to_builtins(value, enc_hook=_numpy_scalar))
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
    schema = msg.schema()
    msg.validate()
    arrays = [(name, _wire_array(msg, name)) for name in schema.array_fields]
    fields = {
        name: value
        for name, value in msgspec.structs.asdict(msg).items()
        if name not in schema.array_fields
    }
    try:
        header = _encoder.encode(
            {
                "type": type(msg).__name__,
                "fp": schema.fingerprint,
                "fields": msgspec.to_builtins(fields, enc_hook=_numpy_scalar),
                "arrays": [[name, a.dtype.str, list(a.shape)] for name, a in arrays],
            }
        )
    except (TypeError, OverflowError, NotImplementedError) as err:
        raise ValueError(f"{type(msg).__name__}.{_unencodable(fields)}: {err}") from err
    # A flat uint8 view, not memoryview.cast: cast refuses shapes with a zero-length axis.
    buffers = [a.reshape(-1).view(np.uint8).data for _, a in arrays]
    return [topic.encode(), header, *buffers]


def decode_header(raw: bytes | memoryview) -> WireHeader:
    """Decode and validate frame 1 alone (cheap: no array is touched)."""
    try:
        return _wire_decoder.decode(raw)
    except (
        msgspec.DecodeError,
        msgspec.ValidationError,
        UnicodeDecodeError,
        ValueError,
        RecursionError,  # a header nested deeper than msgspec's recursion limit
    ) as err:
        # msgspec raises UnicodeDecodeError for invalid UTF-8 in a str, not DecodeError.
        raise FrameDecodeError(f"bad frame header: {err}") from err


def _buffer(frame: Any) -> memoryview:
    buf = getattr(frame, "buffer", frame)
    return memoryview(buf)


def _passthrough(kind: type, obj: Any) -> Any:
    if kind is np.ndarray and isinstance(obj, np.ndarray):
        return obj
    raise NotImplementedError(f"cannot convert {type(obj).__name__} to {kind}")


def decode(frames: Sequence[Any], expect: type[Message] | None = None) -> tuple[str, Message]:
    """Decode ``[topic, header, *buffers]`` (bytes or ``zmq.Frame``) into ``(topic, message)``.

    Args:
        frames: the multipart message as received.
        expect: if given, the frame must carry this type (and its fingerprint).

    Raises:
        FrameDecodeError: truncated, wrong buffer size, unknown type, bad dtype or fields.
        FingerprintMismatchError: same type name, different schema.
    """
    if len(frames) < 2:
        raise FrameDecodeError(f"truncated message: {len(frames)} frame(s), need at least 2")
    try:
        topic = bytes(_buffer(frames[0])).decode()
    except UnicodeDecodeError as err:
        raise FrameDecodeError("topic frame is not UTF-8") from err
    wire = decode_header(_buffer(frames[1]))
    cls = Message.registry.get(wire.type)
    if cls is None:
        raise FrameDecodeError(f"{topic}: unknown message type {wire.type!r}")
    if expect is not None and cls is not expect:
        raise FrameDecodeError(f"{topic}: expected {expect.__name__}, got {wire.type}")
    schema = cls.schema()
    if wire.fp != schema.fingerprint:
        raise FingerprintMismatchError(
            f"{topic}: {wire.type} fingerprint {wire.fp} from the sender, "
            f"{schema.fingerprint} here: the two sides declare different fields"
        )
    if len(frames) != 2 + len(wire.arrays):
        raise FrameDecodeError(
            f"{topic}: {wire.type} header lists {len(wire.arrays)} arrays, got {len(frames) - 2} buffers"
        )
    fields = dict(wire.fields)
    for (name, dtype_str, shape), frame in zip(wire.arrays, frames[2:], strict=True):
        spec = schema.array_fields.get(name)
        if spec is None:
            raise FrameDecodeError(f"{topic}: {wire.type} has no array field {name!r}")
        try:
            dtype = np.dtype(dtype_str)
        except (TypeError, ValueError, SyntaxError) as err:  # numpy's dtype-string parser
            raise FrameDecodeError(f"{topic}: {wire.type}.{name}: bad dtype {dtype_str!r}") from err
        # The wire carries little-endian buffers only ("=f4" and "f4" mean "<f4" here): a
        # big-endian array would reach the node and trip torch.from_numpy and OpenCV.
        if dtype.hasobject or dtype != np.dtype(spec.dtype).newbyteorder("<"):
            raise FrameDecodeError(
                f"{topic}: {wire.type}.{name}: dtype {dtype_str!r}, declared {spec.dtype}"
            )
        if any((not isinstance(n, int)) or n < 0 for n in shape):
            raise FrameDecodeError(f"{topic}: {wire.type}.{name}: bad shape {shape}")
        buf = _buffer(frame)
        want = math.prod(shape) * dtype.itemsize  # Python ints: no int64 wrap-around
        if buf.nbytes != want:
            raise FrameDecodeError(
                f"{topic}: {wire.type}.{name}: buffer of {buf.nbytes} bytes, "
                f"shape {shape} of {dtype_str} needs {want}"
            )
        try:
            array = np.frombuffer(buf, dtype=dtype).reshape(shape)
        except ValueError as err:  # over 64 axes, or an axis past numpy's limit
            raise FrameDecodeError(
                f"{topic}: {wire.type}.{name}: bad shape {shape}: {err}"
            ) from err
        # zmq.Frame buffers are writable, and over inproc they can be the sender's own
        # array: a receiver must never write through to it.
        array.flags.writeable = False
        try:
            spec.check(wire.type, name, array)
        except ValueError as err:
            raise FrameDecodeError(f"{topic}: {err}") from err
        fields[name] = array
    try:
        msg = msgspec.convert(fields, cls, dec_hook=_passthrough)
    except (msgspec.ValidationError, NotImplementedError, TypeError) as err:
        raise FrameDecodeError(f"{topic}: {wire.type}: {err}") from err
    return topic, msg
