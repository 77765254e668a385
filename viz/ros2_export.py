"""Messages as ROS 2 messages (CDR), for a ROS 2 bag a ROS user plays and views as is.

Standard messages where ROS 2 has one, each on a topic of its own:

* ``ToFImage`` -> ``TOPIC/depth`` (``sensor_msgs/Image``, ``32FC1``, metres, NaN where
  invalid), ``TOPIC/ir`` (``mono16``) and ``TOPIC/camera_info`` (``sensor_msgs/CameraInfo``,
  no distortion); frame ``{side}_sensor`` (z along the optical axis, x right, y down: the
  optical frame ROS expects).
* ``MaskImage`` and ``OverlayImage`` -> ``sensor_msgs/Image`` (``mono8``, ``bgr8``).
* ``ContactPatch`` -> ``sensor_msgs/PointCloud2`` (x, y, z float32 and ``bubble`` uint8),
  frame ``tool``.
* ``PoseEstimate`` (status ``ok`` or ``recovered``) and ``GroundTruth`` ->
  ``geometry_msgs/PoseStamped``: the object in the tool frame; the whole message (status,
  residual...) goes to ``TOPIC/full`` in the project's own type.
* ``/tf`` (``tf2_msgs/TFMessage``): ``tool`` -> ``{side}_finger`` at the measured opening
  (from ``GripperState``), ``tool`` -> ``object_estimate`` and ``object_true``;
  ``/tf_static``: ``{side}_finger`` -> ``{side}_sensor``, the camera mounts of
  ``geometry.gripper``.

Every other message goes on its topic in the project's own type, ``softbubble_msgs/msg/NAME``,
whose ``.msg`` definition :func:`msg_definition` writes from the message class (units in
comments): ``Header`` becomes ``std_msgs/Header`` plus ``uint64 seq``, an array field a flat
array (row-major) with a ``NAME_shape`` field when its shape varies, a ``Literal`` a string.
Topics get a leading ``/``. Stamps: ``stamp_nanos`` split into seconds and nanoseconds.
"""

from __future__ import annotations

import json
import math
import typing
from collections.abc import Iterator
from typing import Any

import msgspec
import numpy as np

from geometry.gripper import DEFAULT_GRIPPER, SIDES
from geometry.se3 import quat_from_matrix
from messages.base import Header, Message, describe
from messages.meaning import meaning
from messages.types import (
    ContactPatch,
    GripperState,
    GroundTruth,
    MaskImage,
    OverlayImage,
    PoseEstimate,
    ToFImage,
)

PACKAGE = "softbubble_msgs"
SCALARS = {"int": "int64", "float": "float64", "str": "string", "bool": "bool"}
DTYPES = {
    "f4": "float32",
    "f8": "float64",
    "u1": "uint8",
    "u2": "uint16",
    "u4": "uint32",
    "u8": "uint64",
    "i1": "int8",
    "i2": "int16",
    "i4": "int32",
    "i8": "int64",
    "b1": "bool",
}
TOOL = "tool"

Out = tuple[str, str, Any]  # (ROS topic, ROS type, message object)


def ros_type(type_name: str) -> str:
    """``PoseEstimate`` -> ``softbubble_msgs/msg/PoseEstimate``."""
    return f"{PACKAGE}/msg/{type_name}"


def _comment(type_name: str, name: str) -> str:
    said = meaning(type_name, name)
    parts = [said["unit"]] if "unit" in said else []
    if "note" in said:
        parts.append(said["note"])
    return f"  # {'; '.join(parts)}" if parts else ""


def _lines(type_name: str, fields: list[Any], nested: dict[str, str]) -> list[str]:
    lines = []
    for name, desc in fields:
        note = _comment(type_name, name)
        if isinstance(desc, dict) and desc.get("struct") == "Header":
            lines += ["std_msgs/Header header", "uint64 seq  # per-output sequence number"]
        elif isinstance(desc, dict) and "struct" in desc:
            nested[desc["struct"]] = "\n".join(_lines(desc["struct"], desc["fields"], nested))
            lines.append(f"{ros_type(desc['struct'])} {name}{note}")
        elif isinstance(desc, dict) and "array" in desc:
            element = DTYPES[np.dtype(desc["array"]["dtype"]).str[1:]]
            shape = desc["array"]["shape"]
            if all(isinstance(n, int) for n in shape):
                size = math.prod(shape)
                lines.append(f"{element}[{size}] {name}  # shape {shape}, row-major{note[3:]}")
            else:
                lines.append(f"{element}[] {name}  # row-major, shape in {name}_shape{note[3:]}")
                lines.append(f"uint32[{len(shape)}] {name}_shape")
        elif isinstance(desc, dict) and desc.get("generic") == "list":
            inner = desc["args"][0] if desc.get("args") else "str"
            lines.append(f"{SCALARS.get(str(inner), 'string')}[] {name}{note}")
        elif isinstance(desc, dict) and desc.get("generic") == "Literal":
            values = ", ".join(str(a).strip("'") for a in desc.get("args", []))
            lines.append(f"string {name}  # one of: {values}")
        else:
            lines.append(f"{SCALARS.get(str(desc), 'string')} {name}{note}")
    return lines


def msg_definitions(cls: type[Message]) -> dict[str, str]:
    """The ``.msg`` text of ``cls`` and of the structs it nests, by ROS type name."""
    nested: dict[str, str] = {}
    own = "\n".join(_lines(cls.__name__, describe(cls)["fields"], nested))
    out = {ros_type(name): text for name, text in nested.items()}
    out[ros_type(cls.__name__)] = own
    return out


class Ros2Converter:
    """Converts our messages to message objects of a ``rosbags`` typestore.

    Args:
        typestore: a ROS 2 typestore (``rosbags.typesys.get_typestore``); the project's
            types are registered into it as they are first met.
    """

    def __init__(self, typestore: Any) -> None:
        self.store = typestore
        self.types = typestore.types
        self.registered: dict[str, str] = {}  # ROS type -> .msg text

    def register(self, cls: type[Message]) -> str:
        """Register ``cls`` (and what it nests) in the typestore; returns its ROS type name."""
        from rosbags.typesys import get_types_from_msg

        name = ros_type(cls.__name__)
        if name not in self.registered:
            for ros_name, text in msg_definitions(cls).items():
                if ros_name not in self.types:
                    self.store.register(get_types_from_msg(text, ros_name))
                self.registered[ros_name] = text
        return name

    # -- shared pieces --------------------------------------------------------------------------

    def header(self, nanos: int, frame_id: str) -> Any:
        time = self.types["builtin_interfaces/msg/Time"](
            sec=int(nanos // 1_000_000_000), nanosec=int(nanos % 1_000_000_000)
        )
        return self.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def image(self, array: np.ndarray, encoding: str, nanos: int, frame: str) -> Any:
        data = np.ascontiguousarray(array)
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(nanos, frame),
            height=int(data.shape[0]),
            width=int(data.shape[1]),
            encoding=encoding,
            is_bigendian=int(data.dtype.byteorder == ">"),
            step=int(data.strides[0]),
            data=np.frombuffer(data.tobytes(), np.uint8),
        )

    def transform(self, parent: str, child: str, pose: np.ndarray, nanos: int) -> Any:
        t = self.types
        w, x, y, z = quat_from_matrix(pose[:3, :3])
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(nanos, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](*map(float, pose[:3, 3])),
                rotation=t["geometry_msgs/msg/Quaternion"](
                    x=float(x), y=float(y), z=float(z), w=float(w)
                ),
            ),
        )

    def pose_stamped(self, pose: np.ndarray, nanos: int, frame: str) -> Any:
        t = self.types
        w, x, y, z = quat_from_matrix(pose[:3, :3])
        return t["geometry_msgs/msg/PoseStamped"](
            header=self.header(nanos, frame),
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](*map(float, pose[:3, 3])),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=float(x), y=float(y), z=float(z), w=float(w)
                ),
            ),
        )

    def tf(self, transforms: list[Any]) -> Any:
        return self.types["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def static_tf(self, nanos: int) -> Out:
        """``/tf_static``: each finger's camera mount."""
        mount = DEFAULT_GRIPPER.finger_from_sensor()
        transforms = [self.transform(f"{s}_finger", f"{s}_sensor", mount, nanos) for s in SIDES]
        return "/tf_static", "tf2_msgs/msg/TFMessage", self.tf(transforms)

    # -- our types ------------------------------------------------------------------------------

    def own(self, msg: Message) -> Any:
        """``msg`` in its project type ``softbubble_msgs/msg/NAME``."""
        return self._struct(type(msg), msg, self.register(type(msg)))

    def _struct(self, cls: type[Any], value: Any, name: str) -> Any:
        hints = typing.get_type_hints(cls, include_extras=True)
        fields: dict[str, Any] = {}
        described = dict(describe(cls)["fields"])
        for field in msgspec.structs.fields(cls):
            item = getattr(value, field.name)
            desc = described[field.name]
            if isinstance(item, Header):
                fields["header"] = self.header(item.stamp_nanos, item.frame_id)
                fields["seq"] = int(item.seq)
            elif isinstance(item, msgspec.Struct) and isinstance(desc, dict) and "struct" in desc:
                fields[field.name] = self._struct(
                    hints[field.name], item, ros_type(type(item).__name__)
                )
            elif isinstance(desc, dict) and "array" in desc:
                array = np.asarray(item)
                fields[field.name] = np.ascontiguousarray(array).reshape(-1)
                if not all(isinstance(n, int) for n in desc["array"]["shape"]):
                    fields[f"{field.name}_shape"] = np.array(array.shape, np.uint32)
            elif isinstance(desc, dict) and desc.get("generic") == "list":
                inner = SCALARS.get(str(desc["args"][0]) if desc.get("args") else "str")
                if inner in (None, "string"):
                    fields[field.name] = [v if isinstance(v, str) else json.dumps(v) for v in item]
                else:
                    fields[field.name] = np.array(item, dtype=inner)
            elif isinstance(item, str | bool | int | float):
                fields[field.name] = item
            else:
                fields[field.name] = json.dumps(msgspec.to_builtins(item))
        return self.types[name](**fields)

    # -- one message ----------------------------------------------------------------------------

    def convert(self, topic: str, msg: Message) -> Iterator[Out]:
        """``(ROS topic, ROS type, message)`` for one of ours received on ``topic``."""
        base = "/" + topic.lstrip("/")
        header: Header = msg.header  # type: ignore[attr-defined]
        nanos = int(header.stamp_nanos)
        if isinstance(msg, ToFImage):
            frame = header.frame_id or f"{msg.sensor}_sensor"
            if msg.depth_m.size:
                depth = msg.depth_m.astype(np.float32, copy=False)
                yield (
                    f"{base}/depth",
                    "sensor_msgs/msg/Image",
                    self.image(depth, "32FC1", nanos, frame),
                )
            if msg.ir.size:
                ir = msg.ir.astype(np.uint16, copy=False)
                yield f"{base}/ir", "sensor_msgs/msg/Image", self.image(ir, "mono16", nanos, frame)
            yield f"{base}/camera_info", "sensor_msgs/msg/CameraInfo", self.camera_info(msg, frame)
        elif isinstance(msg, MaskImage):
            frame = header.frame_id or f"{msg.sensor}_sensor"
            yield base, "sensor_msgs/msg/Image", self.image(msg.mask, "mono8", nanos, frame)
        elif isinstance(msg, OverlayImage):
            frame = header.frame_id or f"{msg.sensor}_sensor"
            yield base, "sensor_msgs/msg/Image", self.image(msg.image, "bgr8", nanos, frame)
        elif isinstance(msg, ContactPatch):
            yield base, "sensor_msgs/msg/PointCloud2", self.cloud(msg, header.frame_id or TOOL)
        elif isinstance(msg, PoseEstimate | GroundTruth):
            child = "object_true" if isinstance(msg, GroundTruth) else "object_estimate"
            if isinstance(msg, GroundTruth) or msg.status in ("ok", "recovered"):
                pose = np.asarray(msg.tool_from_object, np.float64)
                yield base, "geometry_msgs/msg/PoseStamped", self.pose_stamped(pose, nanos, TOOL)
                yield (
                    "/tf",
                    "tf2_msgs/msg/TFMessage",
                    self.tf([self.transform(TOOL, child, pose, nanos)]),
                )
            yield f"{base}/full", ros_type(type(msg).__name__), self.own(msg)
        else:
            yield base, ros_type(type(msg).__name__), self.own(msg)
            if isinstance(msg, GripperState):
                fingers = [
                    self.transform(
                        TOOL, f"{s}_finger", DEFAULT_GRIPPER.tool_from_finger(s, msg.width_m), nanos
                    )
                    for s in SIDES
                ]
                yield "/tf", "tf2_msgs/msg/TFMessage", self.tf(fingers)

    def camera_info(self, msg: ToFImage, frame: str) -> Any:
        ref = msg.depth_m if msg.depth_m.size else msg.ir
        k = [msg.fx_px, 0.0, msg.cx_px, 0.0, msg.fy_px, msg.cy_px, 0.0, 0.0, 1.0]
        p = [msg.fx_px, 0.0, msg.cx_px, 0.0, 0.0, msg.fy_px, msg.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0]
        return self.types["sensor_msgs/msg/CameraInfo"](
            header=self.header(msg.header.stamp_nanos, frame),
            height=int(ref.shape[0]),
            width=int(ref.shape[1]),
            distortion_model="plumb_bob",
            d=np.zeros(5),
            k=np.array(k, np.float64),
            r=np.eye(3).reshape(-1),
            p=np.array(p, np.float64),
            binning_x=0,
            binning_y=0,
            roi=self.types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )

    def cloud(self, msg: ContactPatch, frame: str) -> Any:
        n = len(msg.points_in_tool)
        packed = np.zeros(n, dtype=[("xyz", "<f4", 3), ("bubble", "u1"), ("pad", "u1", 3)])
        packed["xyz"] = msg.points_in_tool
        packed["bubble"] = msg.bubble
        field = self.types["sensor_msgs/msg/PointField"]
        fields = [
            field(name="x", offset=0, datatype=7, count=1),
            field(name="y", offset=4, datatype=7, count=1),
            field(name="z", offset=8, datatype=7, count=1),
            field(name="bubble", offset=12, datatype=2, count=1),
        ]
        return self.types["sensor_msgs/msg/PointCloud2"](
            header=self.header(msg.header.stamp_nanos, frame),
            height=1,
            width=n,
            fields=fields,
            is_bigendian=False,
            point_step=packed.itemsize,
            row_step=packed.itemsize * n,
            data=np.frombuffer(packed.tobytes(), np.uint8),
            is_dense=bool(np.isfinite(msg.points_in_tool).all()),
        )
