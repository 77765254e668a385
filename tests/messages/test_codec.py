"""The frame codec: round trips, zero copy, fingerprints, and every way a frame can be bad.

Property tests (hypothesis) cover dtypes, shapes and memory layouts of arrays and the
range of scalar fields; the error tests name each way a frame can be wrong and check
that exactly :class:`FrameDecodeError` comes out; the fuzz tests throw random and
mutated frames at :func:`decode` and allow nothing else to escape.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Annotated, Any

import msgpack
import msgspec
import numpy as np
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from messages import (
    Array,
    ContactPatch,
    FingerprintMismatchError,
    FrameDecodeError,
    Header,
    Message,
    PoseEstimate,
    Pressure,
    Tick,
    ToFImage,
    codec,
    decode,
    decode_header,
    encode,
)
from messages.codec import pack_single, unpack_single
from tests.messages.declare import declare

FAST = settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# Every dtype the declarations in messages/ use, plus the other plain numeric ones.
DECLARED_DTYPES = sorted(
    {spec.dtype for cls in Message.registry.values() for spec in cls.schema().array_fields.values()}
)
PROBE_DTYPES = {
    "f2": "float16",
    "f4": "float32",
    "f8": "float64",
    "i1": "int8",
    "i2": "int16",
    "i4": "int32",
    "i8": "int64",
    "u1": "uint8",
    "u2": "uint16",
    "u4": "uint32",
    "u8": "uint64",
    "b1": "bool",
    "c8": "complex64",
}


def _arr(dtype: str, ndim: int) -> Any:
    return Annotated[np.ndarray, Array(dtype, (None,) * ndim)]


class CodecProbe(Message):
    """Arrays of many dtypes and ranks, 0-d to 3-d, one with a fixed axis (tests only)."""

    header: Header
    f2: _arr("float16", 1)
    f4: _arr("float32", 2)
    f8: _arr("float64", 3)
    i1: _arr("int8", 0)
    i2: _arr("int16", 1)
    i4: _arr("int32", 2)
    i8: _arr("int64", 1)
    u1: _arr("uint8", 3)
    u2: _arr("uint16", 2)
    u4: _arr("uint32", 1)
    u8: _arr("uint64", 2)
    b1: _arr("bool", 2)
    c8: _arr("complex64", 1)
    fixed: Annotated[np.ndarray, Array("float32", (None, 3))]


class CodecScalars(Message):
    """Every kind of scalar field the message types use (declared here: tests only)."""

    header: Header
    count: int
    ratio: float
    name: str
    flag: bool
    counts: list[int]
    ratios: list[float]
    names: list[str]
    flags: list[bool]
    stamps: list[Header]
    blob: Annotated[np.ndarray, Array("uint8", (None,))]


# --------------------------------------------------------------------------- strategies

WIRE_INTS = st.integers(min_value=-(2**63), max_value=2**64 - 1)  # what MessagePack carries
TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=20)
FLOATS = st.floats(allow_nan=True, allow_infinity=True)
HEADERS = st.builds(Header, stamp_nanos=WIRE_INTS, seq=WIRE_INTS, frame_id=TEXT)

LAYOUTS = ("c", "fortran", "big_endian", "strided", "reversed", "big_endian_strided")


def _layout(a: np.ndarray, layout: str) -> np.ndarray:
    """The same values as ``a`` in another memory layout (every result equals ``a``)."""
    if layout == "c":
        return a
    if layout == "big_endian":
        return a.astype(a.dtype.newbyteorder(">"))
    if a.ndim == 0:
        return a  # (np.asfortranarray would make it 1-d)
    if layout == "fortran":
        return np.asfortranarray(a)
    if layout == "strided":
        return np.repeat(a, 2, axis=-1)[..., ::2]
    if layout == "reversed":
        return np.flip(np.flip(a, axis=0).copy(), axis=0)
    if layout == "big_endian_strided":
        return _layout(_layout(a, "big_endian"), "strided")
    raise AssertionError(layout)


@st.composite
def probe_messages(draw: st.DrawFn) -> tuple[CodecProbe, dict[str, np.ndarray]]:
    """A probe message with arrays in assorted layouts, and the C-order values sent."""
    values: dict[str, np.ndarray] = {}
    sent: dict[str, np.ndarray] = {}
    for name, spec in CodecProbe.schema().array_fields.items():
        shape = tuple(want if want is not None else draw(st.integers(0, 5)) for want in spec.shape)
        a = draw(hnp.arrays(np.dtype(spec.dtype), shape))
        values[name] = a
        sent[name] = _layout(a, draw(st.sampled_from(LAYOUTS)))
    msg = CodecProbe(header=draw(HEADERS), **sent)
    return msg, values


def _bits(a: np.ndarray, dtype: str) -> bytes:
    """The little-endian C-order bytes of ``a`` (bitwise: NaN payloads count)."""
    return np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()


def _to_bytes(frames: list[Any]) -> list[bytes]:
    """What a receiver gets from ``recv_multipart(copy=True)``."""
    return [bytes(f) for f in frames]


def _to_zmq(frames: list[Any]) -> list[zmq.Frame]:
    """What a receiver gets from ``recv_multipart(copy=False)``."""
    return [zmq.Frame(bytes(f)) for f in frames]


def _frame_memory(frame: Any) -> np.ndarray:
    return np.frombuffer(getattr(frame, "buffer", frame), dtype=np.uint8)


def _check_arrays_received(msg: Message, wire: list[Any], values: dict[str, np.ndarray]) -> None:
    """Equal values, declared little-endian dtype, read-only views on the frame buffers."""
    for index, (name, spec) in enumerate(type(msg).schema().array_fields.items()):
        got = getattr(msg, name)
        want = values[name]
        assert isinstance(got, np.ndarray), name
        assert got.dtype.str == np.dtype(spec.dtype).newbyteorder("<").str, name
        assert got.shape == want.shape, name
        assert got.tobytes() == _bits(want, spec.dtype), name
        assert not got.flags.writeable, name
        if got.size:
            assert np.shares_memory(got, _frame_memory(wire[2 + index])), name


def _same_scalar(a: Any, b: Any) -> bool:
    """Equality of the same types, where NaN equals NaN and 0.0 differs from -0.0."""
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_scalar(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _header(frames: list[Any]) -> dict[str, Any]:
    header = msgpack.unpackb(bytes(frames[1]), raw=False)
    assert isinstance(header, dict)
    assert set(header) == {"type", "fp", "fields", "arrays"}
    return header


# --------------------------------------------------------------------------- round trips


def test_probe_covers_every_declared_dtype() -> None:
    assert set(DECLARED_DTYPES) <= set(PROBE_DTYPES.values())
    for name, dtype in PROBE_DTYPES.items():
        assert CodecProbe.schema().array_fields[name].dtype == dtype


# One property test checks everything about an array round trip: generating the probe
# (14 arrays) is the expensive part, so each example is used for every check.
@FAST
@given(probe_messages(), TEXT)
def test_array_round_trip(case: tuple[CodecProbe, dict], topic: str) -> None:
    msg, values = case
    frames = encode(topic, msg)
    schema = CodecProbe.schema()

    # The sender sends contiguous little-endian arrays from their own memory.
    for index, name in enumerate(schema.array_fields):
        sent = getattr(msg, name)
        buffer = _frame_memory(frames[2 + index])
        assert buffer.nbytes == sent.nbytes, name
        if sent.size and sent.flags.c_contiguous and sent.dtype.byteorder in "=|<":
            assert np.shares_memory(buffer, sent), name

    # The header reads with plain msgpack.
    header = _header(frames)
    assert header["type"] == "CodecProbe"
    assert header["fp"] == schema.fingerprint
    assert header["fields"] == {"header": msgspec.to_builtins(msg.header)}
    assert [row[0] for row in header["arrays"]] == list(schema.array_fields)
    for (name, dtype, shape), spec in zip(
        header["arrays"], schema.array_fields.values(), strict=True
    ):
        assert dtype == np.dtype(spec.dtype).newbyteorder("<").str, name
        assert shape == list(values[name].shape), name

    # The receiver gets equal values, as read-only views on its frames (bytes or zmq.Frame).
    for wire in (_to_bytes(frames), _to_zmq(frames)):
        got_topic, got = decode(wire, expect=CodecProbe)
        assert got_topic == topic
        assert isinstance(got, CodecProbe)
        assert got.header == msg.header
        _check_arrays_received(got, wire, values)

    # The single-value form (bags): plain msgpack reads it whole, and it unpacks to the
    # same frames byte for byte, its arrays views on the stored value.
    stored = pack_single(frames[1:])
    whole = msgpack.unpackb(stored, raw=False)
    assert whole["fields"] == header["fields"] and whole["type"] == "CodecProbe"
    for name, spec in schema.array_fields.items():
        a = whole["arrays"][name]
        assert a["order"] == "C" and a["shape"] == list(values[name].shape), name
        assert a["data"] == _bits(values[name], spec.dtype), name
    back = unpack_single(stored)
    assert [bytes(f) for f in back] == [bytes(memoryview(f).cast("B")) for f in frames[1:]]
    assert isinstance(decode([b"t", *back], expect=CodecProbe)[1], CodecProbe)


SCALARS = st.builds(
    CodecScalars,
    header=HEADERS,
    count=WIRE_INTS,
    ratio=FLOATS,
    name=TEXT,
    flag=st.booleans(),
    counts=st.lists(WIRE_INTS, max_size=5),
    ratios=st.lists(FLOATS, max_size=5),
    names=st.lists(TEXT, max_size=5),
    flags=st.lists(st.booleans(), max_size=5),
    stamps=st.lists(HEADERS, max_size=3),
    blob=hnp.arrays(np.uint8, st.integers(0, 16)),
)


@FAST
@given(SCALARS)
def test_scalar_round_trip(msg: CodecScalars) -> None:
    frames = encode("scalars/out", msg)
    _, got = decode(_to_bytes(frames), expect=CodecScalars)
    for field in msgspec.structs.fields(CodecScalars):
        if field.name == "blob":
            assert got.blob.tobytes() == msg.blob.tobytes()
            continue
        sent, received = getattr(msg, field.name), getattr(got, field.name)
        assert _same_scalar(sent, received), field.name
    header = _header(frames)
    assert header["fields"]["count"] == msg.count
    assert header["fields"]["name"] == msg.name
    assert header["fields"]["stamps"] == [msgspec.to_builtins(h) for h in msg.stamps]


def test_round_trip_over_a_real_socket_is_zero_copy() -> None:
    depth = np.random.default_rng(0).random((172, 224), dtype=np.float32)
    ir = np.arange(172 * 224, dtype=np.uint16).reshape(172, 224)
    msg = _camera_tof(depth, ir)
    ctx = zmq.Context.instance()
    tx, rx = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    try:
        for sock in (tx, rx):
            sock.linger = 0
            sock.rcvtimeo = 2000
        rx.bind("inproc://codec-zero-copy")
        tx.connect("inproc://codec-zero-copy")
        tx.send_multipart(encode("camera/left", msg), copy=False)
        frames = rx.recv_multipart(copy=False)
    finally:
        tx.close()
        rx.close()
    topic, got = decode(frames, expect=ToFImage)
    assert topic == "camera/left"
    np.testing.assert_array_equal(got.depth_m, depth)
    np.testing.assert_array_equal(got.ir, ir)
    assert np.shares_memory(got.depth_m, _frame_memory(frames[2]))
    assert np.shares_memory(got.ir, _frame_memory(frames[3]))
    # Over inproc with copy=False the frames can be the sender's own arrays (they are here,
    # above pyzmq's copy threshold): the receiver must not be able to write through.
    for received in (got.depth_m, got.ir):
        assert not received.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            received[0, 0] = 0


def test_zero_length_axes_round_trip() -> None:
    patch = ContactPatch(
        header=Header(seq=1),
        points_in_tool=np.zeros((0, 3), np.float32),
        bubble=np.zeros(0, np.uint8),
    )
    _, got = decode(_to_bytes(encode("patch/out", patch)), expect=ContactPatch)
    assert got.points_in_tool.shape == (0, 3)
    assert got.points_in_tool.dtype == np.float32
    assert got.bubble.shape == (0,)


# --------------------------------------------------------------------------- fingerprints

BASE_FIELDS: list[tuple[str, Any]] = [
    ("header", Header),
    ("width_m", float),
    ("image", Annotated[np.ndarray, Array("float32", (None, None))]),
]


def _replace(fields: list[tuple[str, Any]], old: str, new: tuple[str, Any]) -> list:
    return [new if name == old else (name, hint) for name, hint in fields]


VARIANTS: dict[str, list[tuple[str, Any]]] = {
    "added": [*BASE_FIELDS, ("force_n", float)],
    "removed": [f for f in BASE_FIELDS if f[0] != "width_m"],
    "renamed": _replace(BASE_FIELDS, "width_m", ("width_mm", float)),
    "retyped_int": _replace(BASE_FIELDS, "width_m", ("width_m", int)),
    "retyped_str": _replace(BASE_FIELDS, "width_m", ("width_m", str)),
    "retyped_list": _replace(BASE_FIELDS, "width_m", ("width_m", list[float])),
    "array_dtype": _replace(
        BASE_FIELDS, "image", ("image", Annotated[np.ndarray, Array("float64", (None, None))])
    ),
    "array_rank": _replace(
        BASE_FIELDS, "image", ("image", Annotated[np.ndarray, Array("float32", (None,))])
    ),
    "array_fixed_axis": _replace(
        BASE_FIELDS, "image", ("image", Annotated[np.ndarray, Array("float32", (None, 3))])
    ),
    "nested_struct": _replace(
        BASE_FIELDS,
        "header",
        ("header", msgspec.defstruct("Header", [("stamp_nanos", int, 0), ("seq", int, 0)])),
    ),
}


def test_fingerprint_depends_only_on_the_declaration(scratch_registry: dict) -> None:
    first = declare("FpProbe", BASE_FIELDS)
    again = declare("FpProbe", list(BASE_FIELDS))
    assert first is not again
    assert first.schema().fingerprint == again.schema().fingerprint
    assert len(first.schema().fingerprint) == 16
    int(first.schema().fingerprint, 16)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_fingerprint_changes_with_the_fields(variant: str, scratch_registry: dict) -> None:
    base = declare("FpProbe", BASE_FIELDS)
    changed = declare("FpProbe", VARIANTS[variant])
    assert base.schema().fingerprint != changed.schema().fingerprint


def test_fingerprint_changes_with_the_type_name(scratch_registry: dict) -> None:
    one = declare("FpProbeOne", BASE_FIELDS)
    two = declare("FpProbeTwo", BASE_FIELDS)
    assert one.schema().fingerprint != two.schema().fingerprint


def test_fingerprints_of_the_declared_types_are_distinct() -> None:
    fingerprints = [cls.schema().fingerprint for cls in Message.registry.values()]
    assert len(set(fingerprints)) == len(fingerprints)


def test_registry_refuses_a_second_type_of_the_same_name() -> None:
    before = Message.registry["ToFImage"]
    with pytest.raises(TypeError, match="ToFImage"):

        class ToFImage(Message):  # noqa: F811 - the point of the test
            sensor: str

    assert Message.registry["ToFImage"] is before


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_receiver_refuses_another_fingerprint(variant: str, scratch_registry: dict) -> None:
    sender_cls = declare("FpProbe", VARIANTS[variant])
    receiver_cls = declare("FpProbe", BASE_FIELDS, keep=True)
    values: dict[str, Any] = {
        "header": msgspec.convert({"seq": 3}, dict(VARIANTS[variant])["header"]),
        "width_m": 0.05,
        "width_mm": 50.0,
        "force_n": 1.0,
    }
    spec = sender_cls.schema().array_fields["image"]
    shape = tuple(n if n is not None else 2 for n in spec.shape)
    values["image"] = np.zeros(shape, spec.dtype)
    names = {f.name for f in msgspec.structs.fields(sender_cls)}
    if variant.startswith("retyped"):
        values["width_m"] = {"retyped_int": 5, "retyped_str": "5", "retyped_list": [5.0]}[variant]
    msg = sender_cls(**{k: v for k, v in values.items() if k in names})
    frames = encode("probe/out", msg)
    with pytest.raises(FingerprintMismatchError) as info:
        decode(frames)
    assert isinstance(info.value, FrameDecodeError)
    assert sender_cls.schema().fingerprint in str(info.value)
    assert receiver_cls.schema().fingerprint in str(info.value)
    # Control: the receiver's own declaration goes through.
    same = receiver_cls(header=Header(), width_m=1.0, image=np.zeros((2, 2), np.float32))
    assert decode(encode("probe/out", same))[1].width_m == 1.0


def test_wire_fingerprint_mismatch_names_both() -> None:
    frames = _tof_frames()
    header = _header(frames)
    header["fp"] = "0123456789abcdef"
    with pytest.raises(FingerprintMismatchError, match="0123456789abcdef") as info:
        decode([frames[0], msgpack.packb(header), *frames[2:]])
    assert ToFImage.schema().fingerprint in str(info.value)


# --------------------------------------------------------------------------- bad frames


def _tof() -> ToFImage:
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.04, 0.11, (6, 5)).astype(np.float32)
    depth[0, 0] = np.nan
    return ToFImage(
        header=Header(stamp_nanos=10, seq=1, frame_id="left_tof"),
        sensor="left",
        depth_m=depth,
        ir=rng.integers(0, 2**16, (6, 5), dtype=np.uint16),
        fx_px=5.0,
        fy_px=5.0,
        cx_px=2.5,
        cy_px=3.0,
    )


def _tof_frames() -> list[bytes]:
    return _to_bytes(encode("camera/left", _tof()))


def _with_header(edit: Callable[[dict[str, Any]], None]) -> list[bytes]:
    frames = _tof_frames()
    header = _header(frames)
    edit(header)
    return [frames[0], msgpack.packb(header), *frames[2:]]


def _with_array_row(
    index: int, dtype: str | None = None, shape: Any = None, buffer: bytes | None = None
) -> list[bytes]:
    def edit(header: dict[str, Any]) -> None:
        row = header["arrays"][index]
        if dtype is not None:
            row[1] = dtype
        if shape is not None:
            row[2] = shape

    frames = _with_header(edit)
    if buffer is not None:
        frames[2 + index] = buffer
    return frames


def _with_header_bytes(old: bytes, new: bytes) -> list[bytes]:
    """A good frame with ``old`` replaced by ``new`` (the same length) in frame 1's bytes:
    a corruption plain msgpack cannot write, such as a key that is not UTF-8."""
    frames = _tof_frames()
    assert len(old) == len(new) and frames[1].count(old) == 1
    return [frames[0], frames[1].replace(old, new), *frames[2:]]


def _set(path: tuple[str, ...], value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(header: dict[str, Any]) -> None:
        target = header
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return edit


def _drop(path: tuple[str, ...]) -> Callable[[dict[str, Any]], None]:
    def edit(header: dict[str, Any]) -> None:
        target = header
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return edit


def _deeply_nested_header() -> list[bytes]:
    frames = _tof_frames()
    header = _header(frames)
    fields = msgpack.packb(header["fields"])
    # {"x": [[[[...]]]]} far deeper than any decoder's recursion limit, merged into fields.
    deep = b"\xa1x" + b"\x91" * 100_000 + b"\xc0"
    fields = bytes([fields[0] + 1]) + fields[1:] + deep
    rest = {k: v for k, v in header.items() if k != "fields"}
    raw = bytes([0x84]) + msgpack.packb(rest)[1:] + msgpack.packb("fields") + fields
    return [frames[0], raw, *frames[2:]]


BAD_FRAMES: dict[str, Callable[[], list[Any]]] = {
    "no frames": lambda: [],
    "topic only": lambda: _tof_frames()[:1],
    "topic not utf-8": lambda: [b"\xff\xfecamera", *_tof_frames()[1:]],
    "header garbage": lambda: [b"t", b"\x00garbage\xc1", *_tof_frames()[2:]],
    "header empty": lambda: [b"t", b"", *_tof_frames()[2:]],
    "header truncated": lambda: [b"t", _tof_frames()[1][:-3], *_tof_frames()[2:]],
    "header not a map": lambda: [b"t", msgpack.packb([1, 2, 3]), *_tof_frames()[2:]],
    "header trailing bytes": lambda: [b"t", _tof_frames()[1] + b"\x00", *_tof_frames()[2:]],
    "header deeply nested": _deeply_nested_header,
    "header string not utf-8": lambda: [
        b"t",
        msgpack.packb({"type": "ToF\xff", "fp": "", "fields": {}, "arrays": []}).replace(
            "ToF\xff".encode(), b"ToF\xff\xfe"
        ),
    ],
    "dtype string not utf-8": lambda: [
        b"t",
        _with_array_row(0, dtype="<f\xff")[1].replace("<f\xff".encode(), b"<f\xff\xfe"),
        *_tof_frames()[2:],
    ],
    "missing type": lambda: _with_header(_drop(("type",))),
    "missing fp": lambda: _with_header(_drop(("fp",))),
    "missing fields": lambda: _with_header(_drop(("fields",))),
    "missing arrays": lambda: _with_header(_drop(("arrays",))),
    "extra key": lambda: _with_header(_set(("extra",), 1)),
    "type not a string": lambda: _with_header(_set(("type",), 5)),
    "fp not a string": lambda: _with_header(_set(("fp",), None)),
    "fields not a map": lambda: _with_header(_set(("fields",), [1])),
    "arrays not a list": lambda: _with_header(_set(("arrays",), {"a": 1})),
    "array row too short": lambda: _with_header(_set(("arrays",), [["depth_m", "<f4"]])),
    "unknown type": lambda: _with_header(_set(("type",), "NoSuchMessage")),
    "one buffer missing": lambda: _tof_frames()[:-1],
    "one buffer extra": lambda: [*_tof_frames(), b"\x00" * 4],
    "buffer one byte short": lambda: [*_tof_frames()[:2], _tof_frames()[2][:-1], _tof_frames()[3]],
    "buffer one byte long": lambda: [
        *_tof_frames()[:2],
        _tof_frames()[2] + b"\0",
        _tof_frames()[3],
    ],
    "buffer empty": lambda: [*_tof_frames()[:2], b"", _tof_frames()[3]],
    "buffers swapped": lambda: [*_tof_frames()[:2], _tof_frames()[3], _tof_frames()[2]],
    "dtype garbage": lambda: _with_array_row(0, dtype="not-a-dtype"),
    "dtype empty": lambda: _with_array_row(0, dtype=""),
    "dtype unparsable comma list": lambda: _with_array_row(0, dtype="f4,,i4"),
    "dtype bad datetime unit": lambda: _with_array_row(0, dtype="M8[zz]"),
    "dtype object": lambda: _with_array_row(0, dtype="|O"),
    "dtype object of pointer size": lambda: _with_array_row(0, dtype="O8"),
    "dtype structured": lambda: _with_array_row(0, dtype="|V4"),
    "dtype int32 for float32": lambda: _with_array_row(0, dtype="<i4"),
    "dtype big-endian": lambda: _with_array_row(0, dtype=">f4"),
    "dtype big-endian uint16": lambda: _with_array_row(1, dtype=">u2"),
    "dtype float64 for float32": lambda: _with_array_row(0, dtype="<f8", shape=[3, 5]),
    "dtype float32 for uint16": lambda: _with_array_row(1, dtype="<f4", shape=[3, 5]),
    "shape negative": lambda: _with_array_row(0, shape=[-6, -5]),
    "shape float": lambda: _with_array_row(0, shape=[6.0, 5]),
    "shape string": lambda: _with_array_row(0, shape=["6", 5]),
    "shape bool": lambda: _with_array_row(0, shape=[True, 30]),
    "shape not a list": lambda: _with_array_row(0, shape=30),
    "shape too few axes": lambda: _with_array_row(0, shape=[30]),
    "shape too many axes": lambda: _with_array_row(0, shape=[6, 5, 1]),
    "shape no axes": lambda: _with_array_row(0, shape=[]),
    # The byte count matches (6 * 5 * 4 bytes), the number of axes does not.
    "shape over 64 axes": lambda: _with_array_row(0, shape=[1] * 68 + [6, 5]),
    # Products that wrap around in int64 arithmetic must not match an empty buffer.
    "shape product overflows int64": lambda: _with_array_row(0, shape=[2**32, 2**32], buffer=b""),
    "shape product wraps to zero": lambda: _with_array_row(0, shape=[2**62, 4], buffer=b""),
    "shape axis over int64": lambda: _with_array_row(0, shape=[2**64 - 1, 1], buffer=b""),
    "shape zero times huge": lambda: _with_array_row(0, shape=[0, 2**63], buffer=b""),
    "shape huge times zero": lambda: _with_array_row(0, shape=[2**62, 0], buffer=b""),
    "array name unknown": lambda: _with_header(lambda h: h["arrays"][0].__setitem__(0, "depth_mm")),
    "array listed twice, other missing": lambda: _with_header(
        lambda h: h["arrays"][1].__setitem__(0, "depth_m")
    ),
    "array sent as a field": lambda: (
        _with_header(
            lambda h: (h["fields"].__setitem__("depth_m", [1.0] * 30), h["arrays"].pop(0))
        )[:2]
        + _tof_frames()[3:]
    ),
    "scalar field wrong type": lambda: _with_header(_set(("fields", "sensor"), 5)),
    "field outside its declared choices": lambda: _with_header(
        _set(("fields", "sensor"), "middle")
    ),
    "float field given a string": lambda: _with_header(_set(("fields", "fx_px"), "x")),
    "nested struct not a map": lambda: _with_header(_set(("fields", "header"), "h")),
    "nested field wrong type": lambda: _with_header(_set(("fields", "header", "seq"), "1")),
    "required field missing": lambda: _with_header(_drop(("fields", "sensor"))),
    # A key that is not UTF-8 is a corrupted frame, not an unknown field to skip: skipped,
    # the field it named would silently take its default.
    "field key not UTF-8": lambda: _with_header_bytes(b"\xa5fx_px", b"\xa5f\x9e_px"),
    "nested key not UTF-8": lambda: _with_header_bytes(b"\xa3seq", b"\xa3s\x9eq"),
    "field is an ext type": lambda: _with_header(
        _set(("fields", "sensor"), msgpack.ExtType(5, b"xx"))
    ),
}


def test_bad_frame_cases_start_from_a_good_frame() -> None:
    topic, msg = decode(_tof_frames(), expect=ToFImage)
    assert topic == "camera/left"
    np.testing.assert_array_equal(msg.depth_m, _tof().depth_m)
    # Rebuilding the header with plain msgpack alone is still accepted.
    assert isinstance(decode(_with_header(lambda h: None))[1], ToFImage)


@pytest.fixture
def layouts() -> Iterator[dict[Any, Any]]:
    """decode's remembered array layouts of ToFImage, empty for this test."""
    remembered = codec._plan(ToFImage).layouts
    remembered.clear()
    yield remembered
    remembered.clear()


@pytest.mark.parametrize("remembered", [False, True], ids=["first frame", "layout remembered"])
@pytest.mark.parametrize("case", sorted(BAD_FRAMES))
def test_bad_frame_raises_frame_decode_error(
    case: str, remembered: bool, layouts: dict[Any, Any]
) -> None:
    # decode checks a stream's array rows once and then only its fields, buffers and frame
    # count: every bad frame is refused after a good one of the same rows as well.
    if remembered:
        decode(_tof_frames())
        assert layouts
    frames = BAD_FRAMES[case]()
    with pytest.raises(FrameDecodeError):
        decode(frames)


def test_a_remembered_layout_is_used_and_still_refuses_what_differs(
    layouts: dict[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    checked: list[str] = []
    full = codec._layout

    def spy(topic: str, wire_type: str, arrays: Any, plan: Any) -> Any:
        checked.append(wire_type)
        return full(topic, wire_type, arrays, plan)

    monkeypatch.setattr(codec, "_layout", spy)
    good = _tof_frames()
    assert decode(good)[1].header.seq == 1
    assert checked == ["ToFImage"] and len(layouts) == 1
    # The same rows with other fields (the next frame of the stream): not checked again.
    _, again = decode(_with_header(_set(("fields", "header", "seq"), 2)))
    assert again.header.seq == 2 and checked == ["ToFImage"]
    # The same rows, and what the remembered layout does not vouch for is still refused.
    for bad in (
        [*good[:2], good[2][:-1], *good[3:]],  # a buffer one byte short
        good[:-1],  # a buffer missing
        [*good, b""],  # a buffer too many
        _with_header(_set(("fields", "fx_px"), "wide")),  # a field of the wrong type
        _with_header(_drop(("fields", "sensor"))),  # a required field missing
        _with_header(_set(("extra",), 1)),  # an unknown key beside the rows
    ):
        with pytest.raises(FrameDecodeError):
            decode(bad)
    with pytest.raises(FrameDecodeError, match="expected Pressure"):
        decode(good, expect=Pressure)
    # Rows that differ in one byte are checked in full, and refused.
    with pytest.raises(FrameDecodeError, match="dtype"):
        decode(_with_array_row(0, dtype="<f8"))
    assert checked == ["ToFImage"] * 2


@pytest.mark.parametrize("spelling", ["float32", "f4", "=f4", "<f4"])
def test_other_spellings_of_the_declared_dtype_are_accepted(spelling: str) -> None:
    _, msg = decode(_with_array_row(0, dtype=spelling), expect=ToFImage)
    assert msg.depth_m.dtype.str == "<f4"
    assert msg.depth_m.tobytes() == _tof().depth_m.tobytes()


def test_decode_header_alone() -> None:
    wire = decode_header(_tof_frames()[1])
    assert (wire.type, wire.fp) == ("ToFImage", ToFImage.schema().fingerprint)
    assert [row[0] for row in wire.arrays] == ["depth_m", "ir", "tool_from_sensor"]
    with pytest.raises(FrameDecodeError):
        decode_header(b"\x93garbage")


def test_expected_type_mismatch() -> None:
    with pytest.raises(FrameDecodeError, match="Pressure"):
        decode(_tof_frames(), expect=Pressure)


def test_fixed_axis_of_wrong_length_is_refused_on_decode() -> None:
    pose = _pose()
    frames = _to_bytes(encode("pose/out", pose))
    header = _header(frames)
    header["arrays"][0][2] = [2, 8]  # same byte count as 4x4
    with pytest.raises(FrameDecodeError, match="tool_from_object"):
        decode([frames[0], msgpack.packb(header), *frames[2:]])


# --------------------------------------------------------------------------- fast paths

# encode skips the declaration's full check for arrays already as the wire wants them, and
# decode skips numpy's dtype parser for the encoder's spelling: neither may change a byte
# on the wire or let a bad frame through.


def _camera_tof(depth_m: np.ndarray, ir: np.ndarray) -> ToFImage:
    return ToFImage(
        header=Header(stamp_nanos=1_700_000_000_000_000_000, seq=7, frame_id="left_tof"),
        sensor="left",
        depth_m=depth_m,
        ir=ir,
        fx_px=200.0,
        fy_px=200.0,
        cx_px=112.0,
        cy_px=86.0,
    )


SLOW_LAYOUTS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "big-endian": lambda a: _layout(a, "big_endian"),
    "fortran": lambda a: _layout(a, "fortran"),
    "strided": lambda a: _layout(a, "strided"),
    "big-endian strided": lambda a: _layout(a, "big_endian_strided"),
    # Equal to the declared dtype, but not numpy's interned one.
    "uninterned dtype": lambda a: a.view(a.dtype.newbyteorder("=")),
}


@pytest.mark.parametrize("layout", sorted(SLOW_LAYOUTS))
def test_fast_and_slow_encode_paths_send_the_same_bytes(
    layout: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.04, 0.11, (172, 224)).astype(np.float32)
    depth[::7, ::5] = np.nan
    ir = rng.integers(0, 2**16, (172, 224), dtype=np.uint16)
    checked: list[str] = []
    full_check = Array.check

    def spy(spec: Array, type_name: str, field: str, value: np.ndarray) -> None:
        checked.append(field)
        full_check(spec, type_name, field, value)

    monkeypatch.setattr(Array, "check", spy)
    fast = encode("camera/left", _camera_tof(depth, ir))
    assert checked == []  # the fast path took both arrays
    slow_depth, slow_ir = SLOW_LAYOUTS[layout](depth), SLOW_LAYOUTS[layout](ir)
    slow = encode("camera/left", _camera_tof(slow_depth, slow_ir))
    assert checked == ["depth_m", "ir"]  # the slow path took both arrays
    assert _to_bytes(slow) == _to_bytes(fast)
    # Both are exactly what plain msgpack writes for the documented header.
    assert fast[1] == msgpack.packb(
        {
            "type": "ToFImage",
            "fp": ToFImage.schema().fingerprint,
            "fields": {
                "header": {
                    "stamp_nanos": 1_700_000_000_000_000_000,
                    "seq": 7,
                    "frame_id": "left_tof",
                },
                "sensor": "left",
                "fx_px": 200.0,
                "fy_px": 200.0,
                "cx_px": 112.0,
                "cy_px": 86.0,
            },
            "arrays": [
                ["depth_m", "<f4", [172, 224]],
                ["ir", "<u2", [172, 224]],
                ["tool_from_sensor", "<f8", [4, 4]],
            ],
        }
    )
    assert bytes(fast[2]) == depth.tobytes() and bytes(fast[3]) == ir.tobytes()
    # The fast path sends the arrays' own memory.
    assert np.shares_memory(_frame_memory(fast[2]), depth)
    assert np.shares_memory(_frame_memory(fast[3]), ir)


REFUSED_AFTER_A_GOOD_FRAME: dict[str, list[Any]] = {
    # The encoder's spelling for the other array: accepted for ir, never for depth_m.
    "uint16 for depth": [0, "<u2", [6, 10]],
    "float32 for ir": [1, "<f4", [3, 5]],
    "big-endian depth": [0, ">f4", None],
    "int32 depth": [0, "<i4", None],
    "object depth": [0, "|O", None],
    "garbage dtype": [0, "f4,,i4", None],
}


@pytest.mark.parametrize("case", sorted(REFUSED_AFTER_A_GOOD_FRAME))
def test_a_good_frame_does_not_open_the_way_for_a_bad_dtype(case: str) -> None:
    index, dtype, shape = REFUSED_AFTER_A_GOOD_FRAME[case]
    bad = _with_array_row(index, dtype=dtype, shape=shape)
    for _ in range(2):
        assert isinstance(decode(_tof_frames(), expect=ToFImage)[1], ToFImage)
        with pytest.raises(FrameDecodeError, match="dtype"):
            decode(bad)


# --------------------------------------------------------------------------- encode refuses


def _pose(**overrides: Any) -> PoseEstimate:
    values: dict[str, Any] = {
        "header": Header(seq=4),
        "tool_from_object": np.eye(4),
        "residual_rms_m": 0.001,
        "cost": 0.5,
        "iterations": 12,
        "status": "ok",
        "solve_secs": 0.02,
        "points_used": 900,
    }
    values.update(overrides)
    return PoseEstimate(**values)


ENCODE_REFUSALS: dict[str, tuple[Callable[[], Message], str]] = {
    "int depth": (lambda: _replace_field(_tof(), depth_m=np.zeros((6, 5), np.int32)), "depth_m"),
    "float64 depth": (lambda: _replace_field(_tof(), depth_m=np.zeros((6, 5))), "depth_m"),
    "float ir": (lambda: _replace_field(_tof(), ir=np.zeros((6, 5), np.float32)), "ir"),
    "bool ir": (lambda: _replace_field(_tof(), ir=np.zeros((6, 5), bool)), "ir"),
    "object depth": (
        lambda: _replace_field(_tof(), depth_m=np.zeros((6, 5), object)),
        "depth_m",
    ),
    "1-d depth": (lambda: _replace_field(_tof(), depth_m=np.zeros(30, np.float32)), "depth_m"),
    "3-d ir": (lambda: _replace_field(_tof(), ir=np.zeros((6, 5, 1), np.uint16)), "ir"),
    "list depth": (lambda: _replace_field(_tof(), depth_m=[[1.0]]), "depth_m"),
    "pose 3x4": (lambda: _pose(tool_from_object=np.eye(4)[:3]), "tool_from_object"),
    "pose 4x4x1": (lambda: _pose(tool_from_object=np.eye(4)[..., None]), "tool_from_object"),
    "points Nx2": (
        lambda: ContactPatch(
            header=Header(),
            points_in_tool=np.zeros((5, 2), np.float32),
            bubble=np.zeros(5, np.uint8),
        ),
        "points_in_tool",
    ),
    "tick payload int16": (
        lambda: Tick(header=Header(), payload=np.zeros(3, np.int16)),
        "payload",
    ),
}


def _replace_field(msg: Message, **changes: Any) -> Message:
    return msgspec.structs.replace(msg, **changes)


@pytest.mark.parametrize("case", sorted(ENCODE_REFUSALS))
def test_encode_refuses_arrays_that_do_not_fit(case: str) -> None:
    make, field = ENCODE_REFUSALS[case]
    with pytest.raises(ValueError, match=field):
        encode("x/out", make())


def _scalars(**overrides: Any) -> CodecScalars:
    values: dict[str, Any] = {
        "header": Header(seq=1),
        "count": 3,
        "ratio": 0.5,
        "name": "probe",
        "flag": True,
        "counts": [1, 2],
        "ratios": [0.25],
        "names": ["a"],
        "flags": [False],
        "stamps": [],
        "blob": np.zeros(2, np.uint8),
    }
    values.update(overrides)
    return CodecScalars(**values)


SCALAR_REFUSALS: dict[str, tuple[dict[str, Any], str]] = {
    "int past uint64": ({"count": 2**64}, "count"),
    "int below int64": ({"count": -(2**63) - 1}, "count"),
    "list element past uint64": ({"counts": [1, 2**70]}, "counts"),
    "nested int past uint64": ({"header": Header(seq=2**64)}, "header"),
    "arbitrary object": ({"name": object()}, "name"),
    "complex number": ({"ratio": 1 + 2j}, "ratio"),
    "numpy complex": ({"ratio": np.complex64(1)}, "ratio"),
}


@pytest.mark.parametrize("case", sorted(SCALAR_REFUSALS))
def test_encode_refuses_scalars_messagepack_cannot_carry(case: str) -> None:
    overrides, field = SCALAR_REFUSALS[case]
    with pytest.raises(ValueError, match=rf"CodecScalars\.{field}\b"):
        encode("x/out", _scalars(**overrides))


NUMPY_SCALARS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "float32": ({"ratio": np.float32(0.5)}, {"ratio": 0.5}),
    "float64": ({"ratio": np.float64(-2.25)}, {"ratio": -2.25}),
    "float16 nan": ({"ratio": np.float16("nan")}, {"ratio": math.nan}),
    "int64": ({"count": np.int64(-(2**63))}, {"count": -(2**63)}),
    "uint64": ({"count": np.uint64(2**64 - 1)}, {"count": 2**64 - 1}),
    "uint8": ({"count": np.uint8(255)}, {"count": 255}),
    "bool": ({"flag": np.bool_(False)}, {"flag": False}),
    "str": ({"name": np.str_("left")}, {"name": "left"}),
    "lists": (
        {"counts": list(np.arange(3)), "ratios": list(np.ones(2, np.float32))},
        {"counts": [0, 1, 2], "ratios": [1.0, 1.0]},
    ),
    "nested": ({"header": Header(seq=np.int32(7))}, {"header": Header(seq=7)}),
}


@pytest.mark.parametrize("case", sorted(NUMPY_SCALARS))
def test_numpy_scalars_travel_as_python_values(case: str) -> None:
    """Reductions return numpy scalars (``depth.mean()``); a sender may pass them as is."""
    overrides, expected = NUMPY_SCALARS[case]
    _, got = decode(encode("x/out", _scalars(**overrides)), expect=CodecScalars)
    for name, want in expected.items():
        assert _same_scalar(getattr(got, name), want), name
        assert not isinstance(getattr(got, name), np.generic), name


# --------------------------------------------------------------------------- fuzz


def _decode_or_refuse(frames: list[Any]) -> None:
    """Decode; only FrameDecodeError may come out (anything else fails the test)."""
    try:
        topic, msg = decode(frames)
    except FrameDecodeError:
        return
    assert isinstance(topic, str)
    assert isinstance(msg, Message)


def _good_frames() -> list[list[bytes]]:
    patch = ContactPatch(
        header=Header(seq=2),
        points_in_tool=np.arange(12, dtype=np.float32).reshape(4, 3),
        bubble=np.array([0, 0, 1, 1], np.uint8),
    )
    tick = Tick(header=Header(seq=9), value=1.5, payload=np.arange(7, dtype=np.uint8))
    pressure = Pressure(header=Header(), sensor="right", pressure_pa=1000.0)
    return [
        _tof_frames(),
        _to_bytes(encode("pose/out", _pose())),
        _to_bytes(encode("patch/out", patch)),
        _to_bytes(encode("tick/out", tick)),
        _to_bytes(encode("pressure/right", pressure)),
    ]


GOOD_FRAMES = _good_frames()

MSGPACK_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=8)
    | st.sampled_from(["<f4", "<u2", "|u1", "<f8", "f4,,i4", "|O", ">f4", "S0", "depth_m"]),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=10,
)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.binary(max_size=48), max_size=6))
def test_fuzz_random_bytes(frames: list[bytes]) -> None:
    _decode_or_refuse(frames)


@settings(max_examples=150, deadline=None)
@given(MSGPACK_VALUES, st.lists(st.binary(max_size=16), max_size=3))
def test_fuzz_random_msgpack_header(header: Any, buffers: list[bytes]) -> None:
    _decode_or_refuse([b"t", msgpack.packb(header), *buffers])


MUTATIONS = ("flip", "truncate", "drop", "duplicate", "insert", "swap")


@st.composite
def mutated_frames(draw: st.DrawFn) -> list[bytes]:
    frames = list(draw(st.sampled_from(GOOD_FRAMES)))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(MUTATIONS))
        if not frames:
            frames.append(draw(st.binary(max_size=8)))
            continue
        k = draw(st.integers(0, len(frames) - 1))
        if kind == "flip" and frames[k]:
            data = bytearray(frames[k])
            i = draw(st.integers(0, len(data) - 1))
            data[i] ^= draw(st.integers(1, 255))
            frames[k] = bytes(data)
        elif kind == "truncate":
            frames[k] = frames[k][: draw(st.integers(0, len(frames[k])))]
        elif kind == "drop":
            del frames[k]
        elif kind == "duplicate":
            frames.insert(k, frames[k])
        elif kind == "insert":
            frames.insert(k, draw(st.binary(max_size=16)))
        elif kind == "swap":
            j = draw(st.integers(0, len(frames) - 1))
            frames[k], frames[j] = frames[j], frames[k]
    return frames


@settings(max_examples=200, deadline=None)
@given(mutated_frames())
def test_fuzz_mutated_frames(frames: list[bytes]) -> None:
    _decode_or_refuse(frames)


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path into a decoded header (dict keys and list indices), the root excluded."""
    found = []
    items = value.items() if isinstance(value, dict) else enumerate(value)
    for key, child in items:
        found.append((*prefix, key))
        if isinstance(child, dict | list):
            found.extend(_paths(child, (*prefix, key)))
    return found


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_fuzz_mutated_header_values(data: st.DataObject) -> None:
    frames = data.draw(st.sampled_from(GOOD_FRAMES))
    header = _header(frames)
    path = data.draw(st.sampled_from(_paths(header)))
    target = header
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = data.draw(MSGPACK_VALUES)
    _decode_or_refuse([frames[0], msgpack.packb(header), *frames[2:]])


def _stored(edit: Callable[[dict[str, Any]], None]) -> bytes:
    value = msgpack.unpackb(pack_single(_tof_frames()[1:]), raw=False)
    edit(value)
    return msgpack.packb(value)


BAD_STORED: dict[str, Callable[[], bytes]] = {
    "not msgpack": lambda: b"\xc1\xc1",
    "empty": lambda: b"",
    "cut short": lambda: pack_single(_tof_frames()[1:])[:-5],
    "a list, not a map": lambda: msgpack.packb([1, 2]),
    "no arrays": lambda: _stored(lambda v: v.pop("arrays")),
    "unknown key": lambda: _stored(lambda v: v.__setitem__("extra", 1)),
    "data too short": lambda: _stored(
        lambda v: v["arrays"]["ir"].__setitem__("data", v["arrays"]["ir"]["data"][:-2])
    ),
    "Fortran order": lambda: _stored(lambda v: v["arrays"]["ir"].__setitem__("order", "F")),
    "bad dtype": lambda: _stored(lambda v: v["arrays"]["ir"].__setitem__("dtype", "<q9")),
    "object dtype": lambda: _stored(lambda v: v["arrays"]["ir"].__setitem__("dtype", "O")),
    "negative axis": lambda: _stored(lambda v: v["arrays"]["ir"].__setitem__("shape", [-6, -5])),
    "data not bin": lambda: _stored(lambda v: v["arrays"]["ir"].__setitem__("data", "text")),
}


@pytest.mark.parametrize("case", sorted(BAD_STORED))
def test_bad_stored_value_raises_frame_decode_error(case: str) -> None:
    with pytest.raises(FrameDecodeError):
        unpack_single(BAD_STORED[case]())


def test_pack_single_refuses_frames_that_disagree_with_their_header() -> None:
    frames = _tof_frames()
    arrays = len(frames) - 2
    with pytest.raises(FrameDecodeError, match="buffer of"):
        pack_single([*frames[1:-1], frames[-1][:-1]])
    with pytest.raises(FrameDecodeError, match=f"{arrays} arrays, got {arrays - 1}"):
        pack_single(frames[1:-1])
    with pytest.raises(FrameDecodeError, match="bad frame header"):
        pack_single([b"\xc1", *frames[2:]])
