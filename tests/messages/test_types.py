"""Every message type of messages.types round-trips through the codec with a realistic instance.

Instances use the figures of docs/facts.md: 224 x 172 ToF images (depth float32 metres with NaN
for invalid pixels, IR uint16), a pico-flexx-like field of view of about 62 x 45 degrees,
about 1 kPa of inflation, the WSG 50's stroke and force.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import get_args

import msgpack
import msgspec
import numpy as np
import pytest
import zmq

import messages.types
from messages import (
    ClassProbabilities,
    ContactPatch,
    FrameDecodeError,
    GraspState,
    GripperCommand,
    GripperState,
    GroundTruth,
    Header,
    MaskImage,
    Message,
    OverlayImage,
    PoseEstimate,
    Pressure,
    ShearEstimate,
    TaskEvent,
    Tick,
    ToFImage,
    decode,
    describe,
    encode,
)
from messages.tasks import GraspSummary, SortChoice
from messages.types import PoseStatus

WIDTH_PX, HEIGHT_PX = 224, 172
RNG = np.random.default_rng(20201025)


def _header(seq: int = 7, frame_id: str = "left_tof") -> Header:
    return Header(stamp_nanos=1_700_000_000_123_456_789, seq=seq, frame_id=frame_id)


def _depth_m() -> np.ndarray:
    """A bubble seen from inside: 4-11 cm, a dent in the middle, invalid corners."""
    v, u = np.mgrid[0:HEIGHT_PX, 0:WIDTH_PX]
    r2 = ((u - WIDTH_PX / 2) / WIDTH_PX) ** 2 + ((v - HEIGHT_PX / 2) / HEIGHT_PX) ** 2
    depth = 0.11 - 0.05 * np.exp(-r2 / 0.02) + RNG.normal(0.0, 0.0015, r2.shape)
    depth = depth.astype(np.float32)
    depth[r2 > 0.22] = np.nan
    return depth


def _tool_from_object() -> np.ndarray:
    angle = 0.3
    pose = np.eye(4)
    pose[:3, :3] = [
        [math.cos(angle), -math.sin(angle), 0.0],
        [math.sin(angle), math.cos(angle), 0.0],
        [0.0, 0.0, 1.0],
    ]
    pose[:3, 3] = [0.004, -0.002, 0.118]
    return pose


def _tof() -> ToFImage:
    depth = _depth_m()
    ir = RNG.integers(200, 4000, (HEIGHT_PX, WIDTH_PX), dtype=np.uint16)
    ir[np.isnan(depth)] = 0
    return ToFImage(
        header=_header(),
        sensor="left",
        depth_m=depth,
        ir=ir,
        fx_px=(WIDTH_PX / 2) / math.tan(math.radians(31.0)),
        fy_px=(HEIGHT_PX / 2) / math.tan(math.radians(22.5)),
        cx_px=(WIDTH_PX - 1) / 2,
        cy_px=(HEIGHT_PX - 1) / 2,
    )


def _patch() -> ContactPatch:
    n = 2000
    points = RNG.normal([0.0, 0.0, 0.12], [0.01, 0.01, 0.002], (n, 3)).astype(np.float32)
    return ContactPatch(
        header=_header(frame_id="tool"),
        points_in_tool=points,
        bubble=(np.arange(n) >= n // 2).astype(np.uint8),
    )


def _mask() -> MaskImage:
    mask = np.where(np.isfinite(_depth_m()) & (RNG.random((HEIGHT_PX, WIDTH_PX)) > 0.7), 255, 0)
    return MaskImage(header=_header(), sensor="right", mask=mask.astype(np.uint8))


def _shear() -> ShearEstimate:
    shear_px = np.array([1.5, -0.75])
    magnitude = float(np.hypot(*shear_px))
    return ShearEstimate(
        header=_header(),
        sensor="left",
        shear_px=shear_px,
        magnitude_px=magnitude,
        direction=shear_px / magnitude,
        direction_defined=True,
        shear_m=shear_px * 0.4e-3,
        torsion_rad=0.02,
    )


def _probabilities() -> ClassProbabilities:
    logits = np.array([2.0, 0.5, -1.0, 0.1])
    probabilities = (np.exp(logits) / np.exp(logits).sum()).astype(np.float32)
    return ClassProbabilities(
        header=_header(),
        classes=["mug", "screwdriver", "spatula", "bottle"],
        probabilities=probabilities,
        best="mug",
    )


REALISTIC: dict[type[Message], Callable[[], Message]] = {
    ToFImage: _tof,
    Pressure: lambda: Pressure(header=_header(), sensor="right", pressure_pa=1034.2),
    GripperState: lambda: GripperState(
        header=_header(frame_id="wsg50"),
        width_m=0.0625,
        speed_m_per_s=0.0,
        force_n=18.5,
        state="holding",
    ),
    GripperCommand: lambda: GripperCommand(
        header=_header(), command="grasp", width_m=0.03, speed_m_per_s=0.05, force_n=40.0
    ),
    GraspState: lambda: GraspState(
        header=_header(),
        stable=True,
        event="stable",
        pressure_rise_left_pa=182.0,
        pressure_rise_right_pa=166.5,
        finger_speed_m_per_s=0.0004,
    ),
    ContactPatch: _patch,
    MaskImage: _mask,
    PoseEstimate: lambda: PoseEstimate(
        header=_header(frame_id="tool"),
        tool_from_object=_tool_from_object(),
        residual_rms_m=0.0009,
        cost=0.0123,
        iterations=27,
        status="ok",
        solve_secs=0.043,
        points_used=1800,
        solver="ipopt",
        observable=[True, True, True, True, True, False],
    ),
    ShearEstimate: _shear,
    OverlayImage: lambda: OverlayImage(
        header=_header(),
        sensor="left",
        image=RNG.integers(0, 256, (HEIGHT_PX, WIDTH_PX, 3), dtype=np.uint8),
    ),
    ClassProbabilities: _probabilities,
    TaskEvent: lambda: TaskEvent(
        header=_header(),
        task="sort",
        event="summary",
        data=GraspSummary(
            held_secs=1.5,
            pose_statuses={"ok": 12},
            release="mug (0.970) placed in dishwasher",
            sorted=SortChoice(class_name="mug", confidence=0.97, bin="dishwasher"),
        ),
    ),
    GroundTruth: lambda: GroundTruth(
        header=_header(frame_id="world"),
        tool_from_object=_tool_from_object(),
        object_class="mug",
        in_contact=True,
        shear_left_m=np.array([0.6e-3, -0.3e-3]),
        shear_right_m=np.array([-0.55e-3, 0.28e-3]),
        noise_seed=7,
    ),
    Tick: lambda: Tick(
        header=_header(), value=3.25, payload=RNG.integers(0, 256, 1000, dtype=np.uint8)
    ),
}

# Instances that lean on defaults or sit at an edge (no contact, nothing sent).
EDGES: dict[str, Callable[[], Message]] = {
    "command defaults": lambda: GripperCommand(header=Header(), command="home"),
    "state default": lambda: GripperState(
        header=Header(), width_m=0.11, speed_m_per_s=0.0, force_n=0.0
    ),
    "grasp not stable": lambda: GraspState(header=Header(), stable=False),
    "tick defaults": lambda: Tick(header=Header()),
    "empty patch": lambda: ContactPatch(
        header=Header(),
        points_in_tool=np.zeros((0, 3), np.float32),
        bubble=np.zeros(0, np.uint8),
    ),
    "pose without observability": lambda: PoseEstimate(
        header=Header(),
        tool_from_object=np.eye(4),
        residual_rms_m=math.inf,
        cost=math.nan,
        iterations=0,
        status="no_patch",
        solve_secs=0.0,
        points_used=0,
    ),
    "shear without reference": lambda: ShearEstimate(
        header=Header(),
        sensor="right",
        shear_px=np.zeros(2),
        magnitude_px=0.0,
        direction=np.zeros(2),
        direction_defined=False,
        shear_m=np.zeros(2),
        has_reference=False,
    ),
    "no classes": lambda: ClassProbabilities(
        header=Header(), classes=[], probabilities=np.zeros(0, np.float32)
    ),
}


def _assert_same(sent: Message, got: Message) -> None:
    """Field by field: arrays bitwise (NaN included) in the declared little-endian dtype."""
    assert type(got) is type(sent)
    arrays = type(sent).schema().array_fields
    for field in msgspec.structs.fields(type(sent)):
        a, b = getattr(sent, field.name), getattr(got, field.name)
        if field.name in arrays:
            declared = np.dtype(arrays[field.name].dtype).newbyteorder("<")
            assert b.dtype.str == declared.str, field.name
            assert b.shape == a.shape, field.name
            assert b.tobytes() == np.ascontiguousarray(a, dtype=declared).tobytes(), field.name
            assert not b.flags.writeable, field.name
        elif isinstance(a, float) and math.isnan(a):
            assert isinstance(b, float) and math.isnan(b), field.name
        else:
            assert b == a, field.name
            assert type(b) is type(a), field.name


def test_every_type_of_messages_types_has_a_realistic_instance() -> None:
    declared = {
        cls for cls in Message.registry.values() if cls.__module__ == messages.types.__name__
    }
    assert declared == set(REALISTIC)
    for cls, make in REALISTIC.items():
        msg = make()
        assert type(msg) is cls
        msg.validate()


@pytest.mark.parametrize("cls", list(REALISTIC), ids=lambda cls: cls.__name__)
def test_realistic_round_trip(cls: type[Message]) -> None:
    msg = REALISTIC[cls]()
    frames = encode(f"node/{cls.__name__.lower()}", msg)
    for wire in ([bytes(f) for f in frames], [zmq.Frame(bytes(f)) for f in frames]):
        topic, got = decode(wire, expect=cls)
        assert topic == f"node/{cls.__name__.lower()}"
        _assert_same(msg, got)
        for index, name in enumerate(cls.schema().array_fields):
            buffer = np.frombuffer(getattr(wire[2 + index], "buffer", wire[2 + index]), np.uint8)
            if getattr(got, name).size:
                assert np.shares_memory(getattr(got, name), buffer), name


@pytest.mark.parametrize("cls", list(REALISTIC), ids=lambda cls: cls.__name__)
def test_realistic_header_reads_with_plain_msgpack(cls: type[Message]) -> None:
    msg = REALISTIC[cls]()
    frames = encode("node/out", msg)
    header = msgpack.unpackb(bytes(frames[1]), raw=False)
    assert set(header) == {"type", "fp", "fields", "arrays"}
    assert header["type"] == cls.__name__
    assert header["fp"] == cls.schema().fingerprint
    arrays = cls.schema().array_fields
    scalars = {k: v for k, v in msgspec.structs.asdict(msg).items() if k not in arrays}
    assert json.dumps(header["fields"], sort_keys=True) == json.dumps(
        msgspec.to_builtins(scalars), sort_keys=True
    )
    assert [row[0] for row in header["arrays"]] == list(arrays)
    for (name, dtype, shape), frame in zip(header["arrays"], frames[2:], strict=True):
        assert dtype == np.dtype(arrays[name].dtype).newbyteorder("<").str
        assert shape == list(getattr(msg, name).shape)
        assert memoryview(frame).nbytes == math.prod(shape) * np.dtype(dtype).itemsize


@pytest.mark.parametrize("case", sorted(EDGES))
def test_edge_instances_round_trip(case: str) -> None:
    msg = EDGES[case]()
    _, got = decode([bytes(f) for f in encode("node/out", msg)], expect=type(msg))
    _assert_same(msg, got)


def test_tof_image_keeps_invalid_pixels_as_nan() -> None:
    msg = _tof()
    assert msg.depth_m.shape == (HEIGHT_PX, WIDTH_PX)
    _, got = decode([bytes(f) for f in encode("camera/left", msg)], expect=ToFImage)
    invalid = np.isnan(msg.depth_m)
    assert invalid.any() and not invalid.all()
    np.testing.assert_array_equal(np.isnan(got.depth_m), invalid)
    np.testing.assert_array_equal(got.depth_m[~invalid], msg.depth_m[~invalid])


def test_big_endian_and_strided_inputs_arrive_little_endian() -> None:
    msg = _tof()
    sent = msgspec.structs.replace(
        msg,
        depth_m=msg.depth_m.astype(">f4"),
        ir=np.asfortranarray(msg.ir.astype(">u2")),
    )
    _, got = decode([bytes(f) for f in encode("camera/left", sent)], expect=ToFImage)
    _assert_same(msg, got)
    assert got.depth_m.dtype.str == "<f4" and got.ir.dtype.str == "<u2"


@pytest.mark.parametrize("cls", list(REALISTIC), ids=lambda cls: cls.__name__)
def test_description_is_json_and_names_every_field(cls: type[Message]) -> None:
    description = describe(cls)
    assert json.loads(json.dumps(description)) == description
    assert description["type"] == cls.__name__
    assert [row[0] for row in description["fields"]] == [
        f.name for f in msgspec.structs.fields(cls)
    ]
    assert cls.schema().description == description


def test_fingerprints_are_the_same_in_another_process() -> None:
    """A fingerprint must not depend on anything per-process (e.g. hash randomisation)."""
    names = sorted(cls.__name__ for cls in REALISTIC)
    script = (
        "import json, messages\n"
        f"print(json.dumps({{n: messages.message_type(n).schema().fingerprint for n in {names!r}}}))"
    )
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    out = subprocess.run(
        [sys.executable, "-c", script],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    here = {cls.__name__: cls.schema().fingerprint for cls in REALISTIC}
    assert json.loads(out) == here


def test_realistic_frames_are_the_expected_size() -> None:
    """A 224 x 172 depth + IR frame is the two raw images and a small header, nothing more."""
    frames = encode("camera/left", _tof())
    sizes = [memoryview(f).nbytes for f in frames]
    assert sizes[2] == WIDTH_PX * HEIGHT_PX * 4
    assert sizes[3] == WIDTH_PX * HEIGHT_PX * 2
    assert sizes[1] < 512


def test_states_on_the_wire_are_checked_on_decode() -> None:
    """GraspState.event and PoseEstimate.status are Literal types: a misspelt state is
    refused at the receiving edge (and mypy refuses it where the message is built)."""
    good = GraspState(header=Header(stamp_nanos=1), stable=True, event="stable")
    _, back = decode(encode("grasp/grasp", good))
    assert isinstance(back, GraspState) and back.event == "stable"
    bad = GraspState(header=Header(stamp_nanos=1), stable=True, event="stabel")  # type: ignore[arg-type]
    with pytest.raises(FrameDecodeError, match="event"):
        decode(encode("grasp/grasp", bad))
    assert set(get_args(PoseStatus)) >= {"ok", "recovered", "suspect", "no_patch", "failed"}


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (
            GripperState(
                header=Header(), width_m=0.1, speed_m_per_s=0.0, force_n=0.0, state="open"
            ),
            "state",
        ),  # type: ignore[arg-type]
        (GripperCommand(header=Header(), command="open"), "command"),  # type: ignore[arg-type]
        (Pressure(header=Header(), sensor="middle", pressure_pa=0.0), "sensor"),  # type: ignore[arg-type]
    ],
    ids=["gripper state", "gripper command", "sensor"],
)
def test_a_state_command_or_sensor_outside_its_choices_is_refused_on_the_wire(
    msg: Message, field: str
) -> None:
    with pytest.raises(FrameDecodeError, match=rf"Invalid enum value '\w+' - at `\$\.{field}`"):
        decode(encode("a/b", msg))
