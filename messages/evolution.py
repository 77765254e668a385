"""Schema evolution: which stored messages of an older declaration decode as today's type.

A bag stores, beside each type's messages, the description of the type as it was
declared when they were recorded (:func:`messages.base.describe`). When that declaration
is not today's (another fingerprint), a stored message still decodes into today's class
if every difference is a field today's class added *with a default* (the default is
filled in), or a ``str`` field today's class narrowed to a ``Literal`` of strings (each
stored value is checked as it decodes: one outside today's choices is refused, naming
the field and the choices). Anything else is refused with a :class:`SchemaChangeError` naming the type and
the field:

- a stored field today's type no longer has (removed or renamed since);
- a field whose type changed (an array's dtype or shape included);
- a field today's type has, the stored message lacks, and today's type gives no default.

Nested structs (the ``Header``) follow the same rule field by field, named with dots
(``ToFImage.header.frame_id``). The live wire carries no description, so there another
fingerprint is still refused outright (``messages.codec.decode``).
"""

from __future__ import annotations

import typing
from typing import Any

import msgspec

from messages.base import Message, describe_type, fingerprint_of
from messages.errors import SchemaChangeError

# (today's class, stored fingerprint) -> None (readable) or why not; a fingerprint names its
# description (checked before anything is stored here), so the verdict is computed once.
_verdicts: dict[tuple[type[Message], str], str | None] = {}


def check_stored(cls: type[Message], fingerprint: str, description: dict[str, Any] | None) -> None:
    """Raise :class:`SchemaChangeError` unless messages stored as ``description`` (whose
    fingerprint is ``fingerprint``) decode into today's ``cls`` (see the module docstring)."""
    today = cls.schema().fingerprint
    if fingerprint == today:
        return
    key = (cls, fingerprint)
    if key not in _verdicts:
        if description is None:
            raise SchemaChangeError(
                _mismatch(cls, fingerprint, "no stored description to read it by")
            )
        if fingerprint_of(description) != fingerprint:
            raise SchemaChangeError(
                _mismatch(cls, fingerprint, "the stored description does not match its fingerprint")
            )
        _verdicts[key] = _difference(cls, description)
    why = _verdicts[key]
    if why is not None:
        raise SchemaChangeError(_mismatch(cls, fingerprint, why))


def _mismatch(cls: type[Message], fingerprint: str, why: str) -> str:
    return (
        f"{cls.__name__} fingerprint {fingerprint} stored, {cls.schema().fingerprint} today: {why}"
    )


def _difference(cls: type[Message], description: dict[str, Any]) -> str | None:
    """The first difference the rule refuses, as ``Type.field: why``; ``None`` if readable."""
    if description.get("type") != cls.__name__:
        return f"the stored description is of {description.get('type')!r}"
    fields = description.get("fields")
    if not isinstance(fields, list):
        return f"{cls.__name__}: the stored description lists no fields"
    return _struct_difference(cls, fields, cls.__name__, cls.__name__)


def _struct_difference(
    struct: type[msgspec.Struct], stored_fields: list[Any], path: str, type_name: str
) -> str | None:
    hints = typing.get_type_hints(struct, include_extras=True)
    today = {f.name: f for f in msgspec.structs.fields(struct)}
    stored: dict[str, Any] = {}
    for item in stored_fields:
        if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], str)):
            return f"{path}: a stored field is malformed: {item!r}"
        stored[item[0]] = item[1]
    for name in stored:
        if name not in today:
            return f"{path}.{name}: stored, but today's {type_name} has no such field"
    for name, field in today.items():
        where = f"{path}.{name}"
        if name not in stored:
            if field.required:
                return (
                    f"{where}: not in the stored message, and today's {type_name} "
                    "gives it no default"
                )
            continue
        now, then = describe_type(hints[name]), stored[name]
        if now == then or _narrowed_str(then, now):
            continue
        hint = hints[name]
        nested = isinstance(hint, type) and issubclass(hint, msgspec.Struct)
        if nested and isinstance(then, dict) and then.get("struct") == now["struct"]:
            why = _struct_difference(hint, then.get("fields") or [], where, type_name)
            if why is not None:
                return why
            continue
        return f"{where}: stored as {_spelled(then)}, today {_spelled(now)}"
    return None


def _narrowed_str(then: Any, now: Any) -> bool:
    """Whether a field stored as ``str`` is today a ``Literal`` of strings (see above)."""
    return (
        then == "str"
        and isinstance(now, dict)
        and now.get("generic") == "Literal"
        and all(isinstance(a, str) and a[:1] == a[-1:] == "'" for a in now.get("args", []))
    )


def _spelled(description: Any) -> str:
    """A type description as a reader would write it: ``float``, ``array <f4 [None, 3]``."""
    if isinstance(description, dict):
        if "array" in description:
            spec = description["array"]
            return f"array {spec.get('dtype')} {spec.get('shape')}"
        if "struct" in description:
            return f"struct {description['struct']}"
        if "generic" in description:
            args = ", ".join(_spelled(a) for a in description.get("args", []))
            return f"{description['generic']}[{args}]"
    return str(description)
