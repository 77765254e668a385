"""Node parameters: declared once, checked and described from the declaration.

A parameter class is a frozen, keyword-only ``msgspec.Struct`` that refuses unknown
fields; each field declares its type, limits and help with ``Annotated`` and
``msgspec.Meta`` (``rate_hz: Annotated[float, Meta(gt=0, description="...")] = 20.0``),
its choices with ``Literal``, and its unit by its name's suffix (``messages.meaning``).
msgspec checks a mapping (YAML, ``--set``) against it; this module turns msgspec's error
into one :class:`ParamError` naming the dotted field, the declared limit and the value,
describes every parameter for ``launch.py nodes IMPL``, and adds what a declaration cannot
say: numbers must be finite, times and rates must be ones a run can keep, and a field
declared :data:`ExistingFile` must name a readable file (checked when the parameters are
built, so ``launch.py GRAPH --check`` catches a missing file before any node starts).
Checks across fields stay in the class's ``__post_init__``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import msgspec
import msgspec.inspect as mi

from messages.meaning import unit_of

ExistingFile = Annotated[str, msgspec.Meta(extra={"existing_file": True})]
"""A ``str`` field naming a file that must exist and be readable."""


class ParamError(ValueError):
    """A bad parameter: ``path`` (dotted field path, "" when unknown), ``rule``, ``value``.

    ``str()`` reads "winsize must be in [3, 201], got 2"; :meth:`line` gives the graph
    checker's form, ``farneback.winsize: must be in [3, 201], got 2``.
    """

    def __init__(self, path: str, rule: str, value: Any = None, *, has_value: bool = True):
        self.path = path
        self.rule = rule
        self.value = value
        self.has_value = has_value
        super().__init__(self._text())

    def _got(self) -> str:
        return f", got {self.value!r}" if self.has_value else ""

    def _text(self) -> str:
        if not self.path:
            return self.rule
        sep = " " if self.rule.startswith("must") else ": "
        return f"{self.path}{sep}{self.rule}{self._got()}"

    def line(self, prefix: str = "params") -> str:
        """``params.FIELD: RULE, got VALUE`` (or ``params: MESSAGE`` without a field)."""
        if not self.path:
            return f"{prefix}: {self.rule}"
        return f"{prefix}.{self.path}: {self.rule}{self._got()}"


# -- reading a declaration -------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Decl:
    """A field's type with its ``Metadata`` layers folded in, and whether it may be null."""

    type: Any
    nullable: bool = False
    description: str = ""
    existing_file: bool = False


def _decl(t: Any) -> _Decl:
    description, existing, nullable = "", False, False
    while True:
        if isinstance(t, mi.Metadata):
            description = (t.extra_json_schema or {}).get("description", description)
            existing = existing or bool((t.extra or {}).get("existing_file"))
            t = t.type
        elif isinstance(t, mi.UnionType) and t.includes_none and len(t.types) == 2:
            nullable = True
            t = next(x for x in t.types if not isinstance(x, mi.NoneType))
        else:
            return _Decl(t, nullable, description, existing)


def _fields(cls: Any) -> tuple[mi.Field, ...]:
    info = cls if isinstance(cls, mi.StructType) else mi.type_info(cls)
    if not isinstance(info, mi.StructType):
        raise TypeError(f"{cls!r} is no parameter class (a msgspec Struct)")
    return info.fields


def _default(f: mi.Field) -> Any:
    if f.default is not msgspec.NODEFAULT:
        return f.default
    if f.default_factory is not msgspec.NODEFAULT:
        return f.default_factory()
    return msgspec.NODEFAULT


def _num(x: float) -> str:
    return f"{x:g}"


def limits_of(t: Any) -> str:
    """What a type's declaration allows beyond its type: ``> 0``, ``in [3, 201]``,
    ``one of ('a', 'b')``; "" when nothing (a declared length or pattern is not shown)."""
    if isinstance(t, mi.LiteralType):
        return f"one of {tuple(t.values)!r}"
    if isinstance(t, mi.IntType | mi.FloatType):
        low = (">", t.gt) if t.gt is not None else (">=", t.ge) if t.ge is not None else None
        high = ("<", t.lt) if t.lt is not None else ("<=", t.le) if t.le is not None else None
        if low and high:
            left, right = "(" if low[0] == ">" else "[", ")" if high[0] == "<" else "]"
            return f"in {left}{_num(low[1])}, {_num(high[1])}{right}"
        bound = low or high
        return f"{bound[0]} {_num(bound[1])}" if bound else ""
    return ""


_KINDS = (
    (mi.BoolType, "true or false"),
    (mi.IntType, "an integer"),
    (mi.FloatType, "a number"),
    (mi.StrType, "a string"),
    ((mi.StructType, mi.DictType), "a mapping"),
    ((mi.ListType, mi.VarTupleType, mi.TupleType), "a list"),
)


def _kind(decl: _Decl) -> str:
    text = next((text for types, text in _KINDS if isinstance(decl.type, types)), "a value")
    return f"{text} or null" if decl.nullable else text


def _type_name(t: Any) -> str:
    names: dict[type, str] = {
        mi.BoolType: "bool",
        mi.IntType: "int",
        mi.FloatType: "float",
        mi.StrType: "str",
    }
    if isinstance(t, mi.LiteralType):
        return " | ".join(dict.fromkeys(type(v).__name__ for v in t.values))
    if isinstance(t, mi.ListType | mi.VarTupleType):
        return f"list of {_type_name(_decl(t.item_type).type)}"
    if isinstance(t, mi.TupleType):
        return f"list of {len(t.item_types)}"
    return names.get(type(t), type(t).__name__.removesuffix("Type").lower())


# -- what a declaration cannot say -----------------------------------------------------------


def _numbers(value: Any, path: str) -> Iterator[tuple[str, float | int]]:
    if isinstance(value, float | int) and not isinstance(value, bool):
        yield path, value
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from _numbers(item, f"{path}.{key}" if path else str(key))
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{path}[{i}]")


def check_finite(values: Mapping[str, Any], prefix: str = "") -> None:
    """Raise :class:`ParamError` for the first NaN or infinite number, or integer beyond 64
    bits, anywhere in ``values`` (bounded: a graph file's size and depth are, see
    :mod:`messages.files`)."""
    for path, number in _numbers(dict(values), ""):
        if isinstance(number, int):
            if not -(2**63) <= number < 2**64:
                raise ParamError(f"{prefix}{path}", "must be an integer within 64 bits", number)
        elif not math.isfinite(number):
            raise ParamError(f"{prefix}{path}", "must be a finite number", number)


# What a run can do with a time or a rate (a timer's period, a back-off, a timeout): a
# field whose name says seconds or hertz (``param_unit``) is checked against these.
MAX_SECS = 1e6  # 11.6 days: the longest wait, period or timeout a run takes
MIN_PERIOD_SECS = 1e-6  # a rate above 1 MHz is no rate a timer or a device keeps


def timer_period_nanos(period_secs: float) -> int:
    """A timer's period in nanoseconds.

    Raises:
        ValueError: not in [:data:`MIN_PERIOD_SECS`, :data:`MAX_SECS`] (NaN included).
    """
    if not MIN_PERIOD_SECS <= period_secs <= MAX_SECS:
        raise ValueError(
            f"timer period_secs must be in [{MIN_PERIOD_SECS:g}, {MAX_SECS:g}], got {period_secs}"
        )
    return round(period_secs * 1e9)


_COUNTS = ("poly_n", "every_n")  # parameter names whose ``_n`` is a count, not newtons


def param_unit(name: str) -> str:
    """The unit a parameter's name ends in (``messages.meaning``), or ""."""
    return "" if name.endswith(_COUNTS) else unit_of(name) or ""


def _check_units(name: str, value: Any, path: str) -> None:
    if not isinstance(value, float | int) or isinstance(value, bool):
        return
    unit = param_unit(name)
    if unit == "s" and not abs(value) <= MAX_SECS:
        raise ParamError(path, f"must be at most {MAX_SECS:g} s in size", value)
    if unit == "Hz" and value and not 1 / MAX_SECS <= abs(value) <= 1 / MIN_PERIOD_SECS:
        raise ParamError(
            path,
            f"must be 0 or between {1 / MAX_SECS:g} and {1 / MIN_PERIOD_SECS:g} Hz in size "
            f"(a period of {MIN_PERIOD_SECS:g} s to {MAX_SECS:g} s)",
            value,
        )


def _check_fields(cls: Any, built: Any, prefix: str) -> None:
    """Files that must exist, and times and rates a run can use, at every depth."""
    for f in _fields(cls):
        value = getattr(built, f.name)
        decl = _decl(f.type)
        if decl.existing_file and value is not None:
            readable_file(value, f"{prefix}{f.name}")
        _check_units(f.name, value, f"{prefix}{f.name}")
        if isinstance(decl.type, mi.StructType) and value is not None:
            _check_fields(decl.type, value, f"{prefix}{f.name}.")


def readable_file(value: str, path: str) -> None:
    """Raise :class:`ParamError` unless ``value`` names a readable regular file."""
    file = Path(value)
    try:
        exists = file.exists()
    except OSError as err:  # a name the OS refuses (too long)
        raise ParamError(path, f"must name a readable file ({err.strerror})", value) from err
    if not exists:
        raise ParamError(path, "must name an existing file (no such file)", value)
    if not file.is_file():
        raise ParamError(path, "must name a file (it is a directory or special file)", value)
    if not os.access(file, os.R_OK):
        raise ParamError(path, "must name a readable file (permission denied)", value)


def anchor_files(
    cls: Any,
    values: Mapping[str, Any],
    folders: Sequence[Path],
    default_folders: Sequence[Path] = (),
) -> dict[str, Any]:
    """``values`` with each relative :data:`ExistingFile` path (nested ones too) found in
    the first of ``folders`` that has it, made absolute; a path none has stays as it is
    (it is then read from the working directory, and the check names it if missing). A
    relative default that the working directory lacks is looked for in ``default_folders``
    (where the class ships its files) and, found there, written into the result."""
    out = dict(values)
    for f in _fields(cls):
        value = out.get(f.name)
        decl = _decl(f.type)
        if decl.existing_file and isinstance(value, str) and value:
            out[f.name] = _anchor(value, folders)
        default = _default(f)
        if f.name not in out and decl.existing_file and isinstance(default, str) and default:
            found = _anchor(default, default_folders)
            if found != default:
                out[f.name] = found
        if isinstance(decl.type, mi.StructType) and isinstance(value, Mapping):
            out[f.name] = anchor_files(decl.type, value, folders, default_folders)
    return out


def _anchor(value: str, folders: Sequence[Path]) -> str:
    path = Path(value).expanduser()
    if path.is_absolute():
        return value
    for folder in folders:
        found = (folder / path).resolve()
        if found.exists():
            here = path.resolve()
            return value if here.exists() and here.samefile(found) else str(found)
    return value


# -- msgspec's and the classes' messages in the one style ------------------------------------

_AT = re.compile(r"^(?P<msg>.*?)(?: - at `\$(?P<at>[^`]*)`)?$", re.S)
_NAMED = re.compile(r"^Object (?P<what>contains unknown|missing required) field `(?P<name>[^`]+)`$")
_FIELD_FIRST = re.compile(r"^`?(?P<name>[A-Za-z_][A-Za-z0-9_]*)`?(?P<sep>:? )(?P<rest>.*)$", re.S)
_PARTS = re.compile(r"[^.\[\]]+|\[\d+\]")


def _lookup(values: Any, path: str) -> tuple[bool, Any]:
    """The value at a dotted path with ``[i]`` indices, or ``(False, None)``."""
    current = values
    for part in _PARTS.findall(path):
        if part.startswith("["):
            index = int(part[1:-1])
            if not isinstance(current, list | tuple) or index >= len(current):
                return False, None
            current = current[index]
        elif isinstance(current, Mapping) and part in current:
            current = current[part]
        else:
            return False, None
    return True, current


def _declared(cls: Any, path: str) -> tuple[Any, _Decl | None]:
    """The struct at ``path`` (None where it is no struct) and the declaration of the field
    there (None at the top, or where the path leaves the declaration)."""
    decl: _Decl | None = None
    here: Any = mi.type_info(cls)
    for part in _PARTS.findall(path):
        if part.startswith("["):
            if not isinstance(here, mi.ListType | mi.VarTupleType):
                return None, None
            decl = _decl(here.item_type)
        else:
            field = next((f for f in getattr(here, "fields", ()) if f.name == part), None)
            if field is None:
                return None, None
            decl = _decl(field.type)
        here = decl.type
    return (here if isinstance(here, mi.StructType) else None), decl


def rewrite(err: Exception, cls: Any, values: Mapping[str, Any]) -> ParamError:
    """One :class:`ParamError` from msgspec's or a class's own message."""
    match = _AT.match(str(err))
    assert match is not None  # the pattern matches any text
    msg, at = match["msg"].strip(), (match["at"] or "").lstrip(".")
    base = f"{at}." if at else ""
    struct, decl = _declared(cls, at)
    named = _NAMED.match(msg)
    if named:
        path = base + named["name"]
        if named["what"] == "missing required":
            return ParamError(path, "is required (it has no default)", has_value=False)
        takes = ", ".join(f.name for f in struct.fields) if struct is not None else "?"
        name = struct.cls.__name__ if struct is not None else "it"
        return ParamError(path, f"is unknown; {name} takes {takes}", _lookup(values, path)[1])
    if decl is not None and (msg.startswith("Expected `") or msg.startswith("Invalid enum")):
        found, value = _lookup(values, at)
        limits = limits_of(decl.type)
        if isinstance(decl.type, mi.LiteralType) or (", got `" not in msg and limits):
            return ParamError(at, f"must be {limits}", value, has_value=found)
        return ParamError(at, f"must be {_kind(decl)}", value, has_value=found)
    return _own(msg, base, struct, values)


def _own(msg: str, base: str, owner: Any, values: Mapping[str, Any]) -> ParamError:
    """A class's own check: "name must ..." about one field, or a message about several
    (the values of the fields it names are appended)."""
    defaults = (
        {f.name: _default(f) for f in owner.fields} if isinstance(owner, mi.StructType) else {}
    )
    first = _FIELD_FIRST.match(msg)
    if (
        first
        and first["name"] in defaults
        and (first["sep"] == ": " or first["rest"][:4] == "must")
    ):
        path, rule = base + first["name"], first["rest"]
        found, value = _lookup(values, path)
        value = value if found else defaults[first["name"]]
        if rule.startswith("must"):
            return ParamError(path, re.sub(r",? got .*$", "", rule, flags=re.S), value)
        # "`name`: why" (a file that cannot be read): shown once if the text has the value
        return ParamError(path, rule, value, has_value=str(value) not in rule)
    names = [n for n in dict.fromkeys(re.findall(r"[A-Za-z_]\w*", msg)) if n in defaults]
    shown = []
    for name in names:
        found, value = _lookup(values, base + name)
        shown.append(f"{base}{name}={(value if found else defaults[name])!r}")
    text = f"{base.rstrip('.')}: {msg}" if base else msg
    return ParamError(
        "", f"{text}, got {', '.join(shown)}" if shown and " got " not in msg else text
    )


def build_params(cls: type[Any], values: Mapping[str, Any] | None) -> Any:
    """Build ``cls`` from ``values``.

    Raises:
        ParamError: (a ``ValueError``) an unknown key at any depth, a value of the wrong
            type or beyond its declared limits, a NaN or infinite number, an integer beyond
            64 bits, a time (``_secs``) or rate (``_hz``) no run can use
            (:data:`MAX_SECS`, :data:`MIN_PERIOD_SECS`), a missing or unreadable
            :data:`ExistingFile`, or the class's own check; it names the field, what is
            allowed and the value.
    """
    values = dict(values or {})
    check_finite(values)
    try:
        built = msgspec.convert(values, cls, strict=False)
    except (msgspec.ValidationError, ValueError, TypeError) as err:
        raise rewrite(err, cls, values) from err
    _check_fields(cls, built, "")
    return built


def field_names(cls: type[Any]) -> list[str]:
    """The names of a parameter class's fields."""
    return [f.name for f in _fields(cls)]


# -- what a params class takes, for ``launch.py nodes IMPL`` -------------------------------------


class _Required:
    def __repr__(self) -> str:
        return "(required)"


REQUIRED = _Required()  # the default of a parameter that has none


@dataclasses.dataclass(frozen=True)
class ParamInfo:
    """One parameter as ``launch.py nodes IMPL`` shows it."""

    path: str
    type: str
    default: Any
    unit: str
    limits: tuple[str, ...]
    doc: str


def describe(cls: Any, prefix: str = "") -> list[ParamInfo]:
    """Every parameter of ``cls``, nested ones as dotted paths, with default, unit, limits
    and help, all read from the declaration."""
    out: list[ParamInfo] = []
    for f in _fields(cls):
        decl = _decl(f.type)
        if isinstance(decl.type, mi.StructType):
            out += describe(decl.type, f"{prefix}{f.name}.")
            continue
        default = _default(f)
        if decl.existing_file:
            kind = "path of an existing file"
        else:
            kind = _type_name(decl.type) + (" | None" if decl.nullable else "")
        limits = limits_of(decl.type)
        out.append(
            ParamInfo(
                path=f"{prefix}{f.name}",
                type=kind,
                default=REQUIRED if default is msgspec.NODEFAULT else default,
                unit=param_unit(f.name),
                limits=(limits,) if limits else (),
                doc=decl.description,
            )
        )
    return out
