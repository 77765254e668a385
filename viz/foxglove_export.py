"""Messages in Foxglove's well-known schemas, for its MCAP files and its live server.

Foxglove decodes neither MessagePack nor our schema descriptions, so each message is
converted, one Foxglove channel per topic of ours: a ToF image to three,
``TOPIC/depth`` and ``TOPIC/ir`` (``foxglove.RawImage``, ``32FC1`` metres, ``mono16``) and
``TOPIC/calibration`` (``foxglove.CameraCalibration``); masks and overlays to ``RawImage``
(``mono8``, ``bgr8``) and the contact patch to ``foxglove.PointCloud`` (x, y, z float32
and the bubble index, tool frame) on their topic; every other message to JSON on its
topic, with a JSON schema that gives each field's type, unit and meaning
(:func:`json_schema`; arrays of more than :data:`JSON_ARRAY_LIMIT` values are left out).
Poses also go to ``/tf`` as ``foxglove.FrameTransform`` (``tool`` -> ``object_estimate``
for an estimate with status ``ok`` or ``recovered``, ``object_true`` from ground truth,
and ``tool`` -> each camera where each of its frames was taken,
``ToFImage.tool_from_sensor``), where Foxglove's 3D panel looks for them.

:class:`FoxgloveSink` logs into a ``foxglove.Context``: an MCAP writer opened on that
context (``foxglove.open_mcap``) or a WebSocket server (``foxglove.start_server``).
"""

from __future__ import annotations

import json
from typing import Any

import foxglove
import msgspec
import numpy as np
from foxglove import channels as fc
from foxglove import messages as fm

from geometry.se3 import quat_from_matrix
from messages.base import Message, describe
from messages.meaning import meaning
from messages.types import (
    ContactPatch,
    GroundTruth,
    MaskImage,
    OverlayImage,
    PoseEstimate,
    ToFImage,
    pose_is_known,
)

JSON_ARRAY_LIMIT = 64
JSON_TYPES = {"int": "integer", "float": "number", "bool": "boolean", "str": "string"}
TF = "/tf"  # every FrameTransform: Foxglove's 3D panel builds its frame tree from them
_CHANNELS = {
    "RawImage": fc.RawImageChannel,
    "CameraCalibration": fc.CameraCalibrationChannel,
    "PointCloud": fc.PointCloudChannel,
    "FrameTransform": fc.FrameTransformChannel,
}


def _stamp(nanos: int) -> fm.Timestamp:
    return fm.Timestamp(nanos // 1_000_000_000, nanos % 1_000_000_000)


def raw_image(image: np.ndarray, encoding: str, frame_id: str, nanos: int) -> fm.RawImage:
    """A ``RawImage`` of a C-contiguous array (rows of ``width * itemsize * channels``)."""
    data = np.ascontiguousarray(image)
    return fm.RawImage(
        timestamp=_stamp(nanos),
        frame_id=frame_id,
        width=int(data.shape[1]),
        height=int(data.shape[0]),
        encoding=encoding,
        step=int(data.strides[0]),
        data=data.tobytes(),
    )


def frame_transform(parent: str, child: str, pose: np.ndarray, nanos: int) -> fm.FrameTransform:
    """``parent_from_child`` (4x4) as a ``FrameTransform``."""
    w, x, y, z = quat_from_matrix(pose[:3, :3])
    t = pose[:3, 3]
    return fm.FrameTransform(
        timestamp=_stamp(nanos),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=fm.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
        rotation=fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def point_cloud(msg: ContactPatch) -> fm.PointCloud:
    """The contact patch as x, y, z (float32) and ``bubble`` (uint8) in 16-byte points."""
    n = len(msg.points_in_tool)
    packed = np.zeros(n, dtype=[("xyz", "<f4", 3), ("bubble", "u1"), ("pad", "u1", 3)])
    packed["xyz"] = msg.points_in_tool
    packed["bubble"] = msg.bubble
    kind = fm.PackedElementFieldNumericType
    fields = [
        fm.PackedElementField(name="x", offset=0, type=kind.Float32),
        fm.PackedElementField(name="y", offset=4, type=kind.Float32),
        fm.PackedElementField(name="z", offset=8, type=kind.Float32),
        fm.PackedElementField(name="bubble", offset=12, type=kind.Uint8),
    ]
    return fm.PointCloud(
        timestamp=_stamp(msg.header.stamp_nanos),
        frame_id=msg.header.frame_id or "tool",
        point_stride=packed.itemsize,
        fields=fields,
        data=packed.tobytes(),
    )


def to_json(msg: Message) -> dict[str, Any]:
    """A message's fields as JSON values (small arrays as lists, large ones left out)."""
    out: dict[str, Any] = {}
    for name in msg.__struct_fields__:
        value = getattr(msg, name)
        if isinstance(value, np.ndarray):
            if value.size <= JSON_ARRAY_LIMIT:
                out[name] = value.tolist()
        else:
            out[name] = msgspec.to_builtins(value)
    return out


def _json_type(desc: Any, type_name: str, name: str) -> dict[str, Any]:
    said = meaning(type_name, name)
    notes = [f"unit: {said['unit']}"] if "unit" in said else []
    notes += [said["note"]] if "note" in said else []
    out: dict[str, Any]
    if isinstance(desc, dict) and "struct" in desc:
        out = _object(desc["struct"], desc["fields"])
    elif isinstance(desc, dict) and "array" in desc:
        shape = desc["array"]["shape"]
        dtype = np.dtype(desc["array"]["dtype"]).name
        out = {"type": "array", "items": {"type": ["number", "array"]}}
        notes.insert(
            0,
            f"{dtype} array of shape {shape} (nested lists, row-major); "
            f"left out when over {JSON_ARRAY_LIMIT} values",
        )
    elif isinstance(desc, dict) and desc.get("generic") == "list":
        inner = desc["args"][0] if desc.get("args") else "str"
        out = {"type": "array", "items": {"type": JSON_TYPES.get(str(inner), "string")}}
    elif isinstance(desc, dict) and desc.get("generic") == "Literal":
        out = {"type": "string", "enum": [str(a).strip("'") for a in desc.get("args", [])]}
    elif isinstance(desc, dict) and desc.get("generic") in ("Union", "UnionType"):
        out = {"anyOf": [_json_type(a, type_name, name) for a in desc.get("args", [])]}
    elif isinstance(desc, dict) and desc.get("generic") == "dict":
        out = {"type": "object"}
    elif desc == "NoneType":
        out = {"type": "null"}
    elif desc == "Any":
        out = {}
    else:
        out = {"type": JSON_TYPES.get(str(desc), "string")}
    if notes:
        out["description"] = "; ".join(notes)
    return out


def _object(type_name: str, fields: list[Any]) -> dict[str, Any]:
    return {
        "title": type_name,
        "type": "object",
        "properties": {name: _json_type(desc, type_name, name) for name, desc in fields},
    }


def json_schema(cls: type[Message]) -> dict[str, Any]:
    """The JSON schema of ``cls``'s JSON (:func:`to_json`): each field's type, and its unit
    and meaning in ``description`` (from ``messages.meaning``)."""
    schema = _object(cls.__name__, describe(cls)["fields"])
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


def convert(topic: str, msg: Message) -> list[tuple[str, str, Any]]:
    """``(foxglove topic, schema kind, message)`` for one of ours; kind ``"json"`` is a dict.

    One channel per topic of ours (a ToF image: depth, IR and calibration); poses also to
    ``/tf``."""
    nanos = int(msg.header.stamp_nanos)  # type: ignore[attr-defined]
    frame = getattr(msg.header, "frame_id", "")  # type: ignore[attr-defined]
    if isinstance(msg, ToFImage):
        frame = frame or f"{msg.sensor}_sensor"
        images: list[tuple[str, str, Any]] = []
        if msg.depth_m.size:
            depth = raw_image(msg.depth_m, "32FC1", frame, nanos)
            images.append((f"{topic}/depth", "RawImage", depth))
        if msg.ir.size:
            images.append((f"{topic}/ir", "RawImage", raw_image(msg.ir, "mono16", frame, nanos)))
        ref = msg.depth_m if msg.depth_m.size else msg.ir
        k = [msg.fx_px, 0.0, msg.cx_px, 0.0, msg.fy_px, msg.cy_px, 0.0, 0.0, 1.0]
        calibration = fm.CameraCalibration(
            timestamp=_stamp(nanos),
            frame_id=frame,
            width=int(ref.shape[1]),
            height=int(ref.shape[0]),
            distortion_model="plumb_bob",
            D=[0.0] * 5,
            K=k,
            R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            P=[msg.fx_px, 0.0, msg.cx_px, 0.0, 0.0, msg.fy_px, msg.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0],
        )
        images.append((f"{topic}/calibration", "CameraCalibration", calibration))
        if pose_is_known(msg.tool_from_sensor):
            # Where this frame was taken (its source placed it: the scene's or the rig
            # calibration's mount at the opening of its stamp).
            camera = frame_transform("tool", frame, msg.tool_from_sensor, nanos)
            images.append((TF, "FrameTransform", camera))
        return images
    if isinstance(msg, MaskImage):
        return [(topic, "RawImage", raw_image(msg.mask, "mono8", frame, nanos))]
    if isinstance(msg, OverlayImage):
        return [(topic, "RawImage", raw_image(msg.image, "bgr8", frame, nanos))]
    if isinstance(msg, ContactPatch):
        return [(topic, "PointCloud", point_cloud(msg))]
    out: list[tuple[str, str, Any]] = [(topic, "json", to_json(msg))]
    if isinstance(msg, PoseEstimate) and msg.status in ("ok", "recovered"):
        pose = frame_transform("tool", "object_estimate", msg.tool_from_object, nanos)
        out.append((TF, "FrameTransform", pose))
    elif isinstance(msg, GroundTruth):
        pose = frame_transform("tool", "object_true", msg.tool_from_object, nanos)
        out.append((TF, "FrameTransform", pose))
    return out


class FoxgloveSink:
    """Logs our messages into a ``foxglove.Context`` (one channel per converted topic)."""

    def __init__(self, context: foxglove.Context) -> None:
        self.context = context
        self.channels: dict[str, Any] = {}
        self.written = 0

    def _channel(self, topic: str, kind: str, cls: type[Message]) -> Any:
        channel = self.channels.get(topic)
        if channel is None:
            if kind == "json":
                schema = json_schema(cls)
                channel = foxglove.Channel(
                    topic,
                    schema=foxglove.Schema(
                        name=cls.__name__, encoding="jsonschema", data=json.dumps(schema).encode()
                    ),
                    message_encoding="json",
                    context=self.context,
                )
            else:
                channel = _CHANNELS[kind](topic, context=self.context)
            self.channels[topic] = channel
        return channel

    def log(self, topic: str, msg: Message, log_time_nanos: int) -> None:
        """Convert and log one message received on ``topic`` at ``log_time_nanos``."""
        for fox_topic, kind, value in convert(topic, msg):
            channel = self._channel("/" + fox_topic.lstrip("/"), kind, type(msg))
            if kind == "json":
                channel.log(json.dumps(value).encode(), log_time=log_time_nanos)
            else:
                channel.log(value, log_time=log_time_nanos)
            self.written += 1
