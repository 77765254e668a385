"""What a bag says about each channel: the message type, and how to read it without this project.

Each channel's MCAP schema (encoding ``softbubble.description+json``) is a JSON object:

- ``type``, ``fingerprint``: the message type and its schema fingerprint at record time;
- ``packing``: how a message is stored (see :mod:`runtime.bag.packing`);
- ``description``: :func:`messages.base.describe` of the type at record time (every field
  and its Python type), so an old bag decodes after a field changed;
- ``layout``, ``fields``, ``arrays``, ``conventions`` (bags written since the
  single-value packing): what a reader in another language needs, field by field: the
  MessagePack type with its width, the unit, what special values mean, and for arrays
  dtype, byte order, memory order and shape. Units come from the field name's suffix
  (``_m``, ``_pa``, ``_nanos``...); :data:`NOTES` adds what a name cannot say.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from messages.base import Message, fingerprint_of
from messages.errors import SchemaChangeError
from messages.evolution import check_stored
from messages.meaning import JS_INT, POSE_NOTE, meaning
from runtime.bag.packing import PACKING

SCHEMA_ENCODING = "softbubble.description+json"

CONVENTIONS = {
    "units": "SI, the unit in the field name (width_m, pressure_pa, stamp_nanos, solve_secs)",
    "frames": (
        "tool (gripper tool frame), left_sensor and right_sensor (each ToF camera, z along "
        "the optical axis), object (object geometry frame); right-handed"
    ),
    "poses": POSE_NOTE,
    "quaternions": "(w, x, y, z), unit norm, where they appear",
    "images": "(rows, columns[, channels]), row 0 at the top, column 0 at the left",
    "integers": JS_INT,
    "floats": "MessagePack float 64 (IEEE 754 double)",
}

LAYOUT = (
    "each MCAP message is ONE MessagePack map: {'type': str, 'fp': str, 'fields': map of "
    "the scalar fields (nested structs as maps), 'arrays': map name -> {'dtype': numpy "
    "dtype string, 'shape': [int], 'order': 'C', 'data': bin}}"
)


def _scalar_type(desc: Any) -> str:
    """A described scalar type as a reader in another language sees it."""
    if isinstance(desc, dict) and "generic" in desc:
        args = [_scalar_type(a) for a in desc.get("args", [])]
        return f"{desc['generic']}[{', '.join(args)}]"
    return {"int": "int64", "float": "float64", "bool": "bool", "str": "string"}.get(
        str(desc), str(desc)
    )


def _fields(type_name: str, prefix: str, described: list[Any], out: dict[str, Any]) -> None:
    for name, desc in described:
        path = f"{prefix}{name}"
        if isinstance(desc, dict) and "struct" in desc:
            _fields(desc["struct"], f"{path}.", desc.get("fields", []), out)
            continue
        if isinstance(desc, dict) and "array" in desc:
            continue
        out[path] = {"type": _scalar_type(desc), **meaning(type_name, name)}


def _arrays(type_name: str, described: list[Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, desc in described:
        if not (isinstance(desc, dict) and "array" in desc):
            continue
        dtype = np.dtype(desc["array"]["dtype"]).newbyteorder("<")
        entry: dict[str, Any] = {
            "dtype": dtype.str,
            "type": dtype.name,
            "byte_order": "little" if dtype.itemsize > 1 else "n/a (1 byte)",
            "order": "C (row-major)",
            "shape": desc["array"]["shape"],  # null = any length on that axis
            **meaning(type_name, name),
        }
        out[name] = entry
    return out


def reader_guide(description: dict[str, Any]) -> dict[str, Any]:
    """The ``layout``, ``fields``, ``arrays`` and ``conventions`` of a channel's schema."""
    type_name = str(description.get("type", ""))
    described = description.get("fields", [])
    fields: dict[str, Any] = {}
    _fields(type_name, "", described, fields)
    return {
        "layout": LAYOUT,
        "fields": fields,
        "arrays": _arrays(type_name, described),
        "conventions": CONVENTIONS,
    }


@dataclass(frozen=True)
class TopicSchema:
    """What a bag knows of the type on one channel, independent of today's classes."""

    type_name: str
    fingerprint: str
    description: dict[str, Any] | None
    packing: str = PACKING

    def to_json(self) -> bytes:
        body: dict[str, Any] = {
            "type": self.type_name,
            "fingerprint": self.fingerprint,
            "description": self.description,
            "packing": self.packing,
        }
        if self.description is not None and self.packing == PACKING:
            body.update(reader_guide(self.description))
        return json.dumps(body, sort_keys=True, indent=1).encode()

    @staticmethod
    def from_json(data: bytes | str, name: str = "", packing: str = "") -> TopicSchema:
        """Read a stored schema (either packing); missing or broken parts become unknown."""
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
            packing=packing or str(obj.get("packing") or PACKING),
        )

    @functools.cached_property
    def refused(self) -> str:
        """Why this schema cannot be trusted ("" when it can): a stored description whose
        fingerprint is not the one stored with it was edited after the recording."""
        if self.description is None or not self.fingerprint:
            return ""
        if fingerprint_of(self.description) != self.fingerprint:
            return (
                f"the stored schema of {self.type_name} does not match its fingerprint "
                f"{self.fingerprint} (edited after recording?): its messages are refused"
            )
        return ""

    def field_mismatch(self, fields: dict[str, Any]) -> str | None:
        """The first scalar field of a decoded message whose value does not fit its stored
        type (``'value': expected float, got 'abc'``), or None (also when unknown)."""
        described = (self.description or {}).get("fields")
        if not isinstance(described, list):
            return None
        return _mismatch(fields, described, "")

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

    def current_class(self) -> type[Message]:
        """Today's class of this type, into which the stored messages decode.

        The same fingerprint, or an older declaration whose every difference is a field
        today's class added with a default (``messages.evolution``).

        Raises:
            SchemaChangeError: the type is not declared today, or its declaration changed
                in a way the rule refuses (the message names the type and the field).
        """
        cls = Message.registry.get(self.type_name)
        if cls is None:
            raise SchemaChangeError(f"{self.type_name} is not declared today")
        check_stored(cls, self.fingerprint, self.description)
        return cls


_SCALARS: dict[str, tuple[type, ...]] = {
    "int": (int,),
    "float": (int, float),
    "str": (str,),
    "bool": (bool,),
    "NoneType": (type(None),),
    "bytes": (bytes,),
}


def _fits(value: Any, desc: Any) -> bool:
    """Whether a plain decoded value fits a described type (unknown kinds fit)."""
    if isinstance(desc, str):
        kinds = _SCALARS.get(desc)
        if kinds is None:
            return True  # an enum or a type no plain value can be checked against
        return isinstance(value, kinds) and (desc == "bool" or not isinstance(value, bool))
    if not isinstance(desc, dict):
        return True
    if "struct" in desc:
        return isinstance(value, dict) and _mismatch(value, desc.get("fields") or [], "") is None
    generic, args = desc.get("generic"), desc.get("args") or []
    if generic in ("Union", "UnionType", "Optional"):
        return any(_fits(value, a) for a in args)
    if generic in ("tuple", "list"):
        if not isinstance(value, list | tuple):
            return False
        if generic == "tuple" and args and "ellipsis" not in args and len(args) != len(value):
            return False
        each = args[:1] * len(value) if generic == "list" or "ellipsis" in args else args
        return all(_fits(v, a) for v, a in zip(value, each, strict=False))
    if generic == "dict":
        return isinstance(value, dict)
    return True


def _mismatch(fields: dict[str, Any], described: list[Any], prefix: str) -> str | None:
    for item in described:
        if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], str)):
            continue
        name, desc = item
        if name not in fields or (isinstance(desc, dict) and "array" in desc):
            continue
        if not _fits(fields[name], desc):
            return f"field {prefix}{name!r}: expected {_spelled(desc)}, got {fields[name]!r:.60}"
    return None


def _spelled(desc: Any) -> str:
    if isinstance(desc, dict) and "struct" in desc:
        return f"struct {desc['struct']}"
    if isinstance(desc, dict) and "generic" in desc:
        return f"{desc['generic']}[{', '.join(_spelled(a) for a in desc.get('args') or [])}]"
    return str(desc)


def schema_for(type_name: str, fingerprint: str) -> TopicSchema:
    """The schema to store for frames of ``type_name``/``fingerprint`` seen on the wire."""
    cls = Message.registry.get(type_name)
    description = None
    if cls is not None and cls.schema().fingerprint == fingerprint:
        description = cls.schema().description
    return TopicSchema(type_name, fingerprint, description)


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of a bag: its topic, schema and where it was declared."""

    channel_id: int
    topic: str
    schema: TopicSchema
    message_encoding: str = "msgpack"
    offset: int = -1  # file offset of the record that declared it (-1: inside a chunk)
