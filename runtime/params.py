"""Typed node parameters from plain mappings (YAML, ``--set``), with one error style.

Parameter classes are frozen, keyword-only dataclasses that check their own values in
``__post_init__`` and raise ``ValueError`` naming the field: "`rate_hz` must be > 0,
got -3". This module adds the checks every class shares (unknown keys at any depth,
wrong types, NaN or infinite numbers, paths that must name a readable file) and turns
every failure, msgspec's included, into one :class:`ParamError` that names the field
(a dotted path for nested parameters), what is allowed, and the value given.

A field declares that it is a path to an existing, readable file with
:data:`ExistingFile` (``model: ExistingFile = "models/net.pt"``); it is checked when
the parameters are built, so ``launch.py GRAPH --check`` catches a missing file before
any node starts.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import msgspec


class _MustExist:
    """Annotation marker: this ``str`` field names a file that must exist and be readable."""

    def __repr__(self) -> str:
        return "ExistingFile"


MUST_EXIST = _MustExist()
ExistingFile = Annotated[str, MUST_EXIST]


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


# -- declarations ----------------------------------------------------------------------------


def field_hints(cls: type[Any]) -> dict[str, Any]:
    """Resolved type hints of a params dataclass, ``Annotated`` metadata kept."""
    return typing.get_type_hints(cls, include_extras=True)


def _dataclass_of(hint: Any) -> type[Any] | None:
    """The params dataclass a field holds (through ``Annotated`` and ``X | None``), if any."""
    if typing.get_origin(hint) is Annotated:
        hint = typing.get_args(hint)[0]
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return hint
    if typing.get_origin(hint) not in (typing.Union, types.UnionType):
        return None
    options = [a for a in typing.get_args(hint) if a is not type(None)]
    if len(options) == 1 and isinstance(options[0], type) and dataclasses.is_dataclass(options[0]):
        return options[0]
    return None


def _must_exist(hint: Any) -> bool:
    return typing.get_origin(hint) is Annotated and any(
        m is MUST_EXIST for m in typing.get_args(hint)[1:]
    )


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


# -- the checks every class shares -------------------------------------------------------------


def _unknown_keys(cls: type[Any], values: Mapping[str, Any], prefix: str) -> None:
    hints = field_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for key, value in values.items():
        path = f"{prefix}{key}"
        if key not in names:
            raise ParamError(path, f"is unknown; {cls.__name__} takes {', '.join(names)}", value)
        nested = _dataclass_of(hints[key])
        if nested is not None and isinstance(value, Mapping):
            _unknown_keys(nested, value, f"{path}.")


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
# field whose name says seconds or hertz (``unit_of``) is checked against these.
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


def _check_units(name: str, value: Any, path: str) -> None:
    if not isinstance(value, float | int) or isinstance(value, bool):
        return
    unit = unit_of(name)
    if unit == "s" and not abs(value) <= MAX_SECS:
        raise ParamError(path, f"must be at most {MAX_SECS:g} s in size", value)
    if unit == "Hz" and value and not 1 / MAX_SECS <= abs(value) <= 1 / MIN_PERIOD_SECS:
        raise ParamError(
            path,
            f"must be 0 or between {1 / MAX_SECS:g} and {1 / MIN_PERIOD_SECS:g} Hz in size "
            f"(a period of {MIN_PERIOD_SECS:g} s to {MAX_SECS:g} s)",
            value,
        )


def _check_fields(cls: type[Any], built: Any, prefix: str) -> None:
    """Files that must exist, and times and rates a run can use, at every depth."""
    hints = field_hints(cls)
    for f in dataclasses.fields(cls):
        value = getattr(built, f.name)
        if _must_exist(hints[f.name]):
            readable_file(value, f"{prefix}{f.name}")
        _check_units(f.name, value, f"{prefix}{f.name}")
        nested = _dataclass_of(hints[f.name])
        if nested is not None and value is not None:
            _check_fields(nested, value, f"{prefix}{f.name}.")


def anchor_files(
    cls: type[Any],
    values: Mapping[str, Any],
    folders: Sequence[Path],
    default_folders: Sequence[Path] = (),
) -> dict[str, Any]:
    """``values`` with each relative :data:`ExistingFile` path (nested ones too) found in
    the first of ``folders`` that has it, made absolute; a path none has stays as it is
    (it is then read from the working directory, and the check names it if missing). A
    relative default that the working directory lacks is looked for in ``default_folders``
    (where the class ships its files) and, found there, written into the result."""
    hints = field_hints(cls)
    out = dict(values)
    for f in dataclasses.fields(cls):
        value = out.get(f.name)
        if _must_exist(hints[f.name]) and isinstance(value, str) and value:
            out[f.name] = _anchor(value, folders)
        default = _default(f)
        if (
            f.name not in out
            and _must_exist(hints[f.name])
            and isinstance(default, str)
            and default
        ):
            found = _anchor(default, default_folders)
            if found != default:
                out[f.name] = found
        nested = _dataclass_of(hints[f.name])
        if nested is not None and isinstance(value, Mapping):
            out[f.name] = anchor_files(nested, value, folders, default_folders)
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


# -- msgspec's and the classes' messages in the one style ------------------------------------

_AT = re.compile(r"^(?P<msg>.*?)(?: - at `\$(?P<at>[^`]*)`)?$", re.S)
_EXPECTED = re.compile(r"^Expected `(?P<type>[^`]+)`(?P<rule>[^,]*)(?:, got `(?P<got>[^`]+)`)?$")
_MISSING = re.compile(r"^Object missing required field `(?P<name>[^`]+)`$")
_FIELD_FIRST = re.compile(r"^`?(?P<name>[A-Za-z_][A-Za-z0-9_]*)`?(?P<sep>:? )(?P<rest>.*)$", re.S)
_TYPES = {
    "int": "an integer",
    "float": "a number",
    "str": "a string",
    "bool": "true or false",
    "array": "a list",
    "object": "a mapping",
    "null": "null",
}


def _lookup(values: Any, path: str) -> tuple[bool, Any]:
    """The value at a dotted path with ``[i]`` indices, or ``(False, None)``."""
    current = values
    for part in re.findall(r"[^.\[\]]+|\[\d+\]", path):
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


def _field_of(cls: type[Any], at: str) -> tuple[type[Any] | None, dict[str, Any]]:
    """The dataclass and the field defaults at a dotted msgspec path (``.farneback``)."""
    current: type[Any] | None = cls
    for part in [p for p in at.split(".") if p]:
        if current is None or not dataclasses.is_dataclass(current):
            return None, {}
        current = _dataclass_of(field_hints(current).get(part))
    if current is None:
        return None, {}
    return current, {f.name: _default(f) for f in dataclasses.fields(current)}


def _describe_type(text: str) -> str:
    return " or ".join(_TYPES.get(part.strip(), f"`{part.strip()}`") for part in text.split("|"))


def rewrite(err: Exception, cls: type[Any], values: Mapping[str, Any]) -> ParamError:
    """One :class:`ParamError` from msgspec's or a class's own message."""
    match = _AT.match(str(err))
    assert match is not None  # the pattern matches any text
    msg, at = match["msg"].strip(), (match["at"] or "").lstrip(".")
    expected = _EXPECTED.match(msg)
    if expected:
        found, value = _lookup(values, at)
        rule = f"must be {_describe_type(expected['type'])}{expected['rule']}"
        return ParamError(at, rule, value, has_value=found)
    missing = _MISSING.match(msg)
    if missing:
        path = f"{at}.{missing['name']}" if at else missing["name"]
        return ParamError(path, "is required (it has no default)", has_value=False)
    # A class's own check: "`name` must be ..., got ..." or "`name`: why" (at its level).
    owner, defaults = _field_of(cls, at)
    first = _FIELD_FIRST.match(msg)
    base = f"{at}." if at else ""
    if owner is not None and first and first["name"] in defaults:
        path = base + first["name"]
        rest = first["rest"]
        if first["sep"] == " " and not rest.startswith("must"):
            return _several(msg, base, defaults, values)
        rest = re.sub(r",? got .*$", "", rest, flags=re.S) if rest.startswith("must") else rest
        found, value = _lookup(values, path)
        if not found:
            value, found = defaults[first["name"]], True
        if not rest.startswith("must") and str(value) in rest:
            found = False  # the class's message already shows the value
        return ParamError(path, rest, value, has_value=found)
    return _several(msg, base, defaults, values)


def _several(
    msg: str, base: str, defaults: dict[str, Any], values: Mapping[str, Any]
) -> ParamError:
    """A message about no one field: the values of the fields it names are appended."""
    named = [n for n in dict.fromkeys(re.findall(r"[A-Za-z_]\w*", msg)) if n in defaults]
    shown = []
    for name in named:
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
            type, a NaN or infinite number, an integer beyond 64 bits, a time (``_secs``)
            or rate (``_hz``) no run can use (:data:`MAX_SECS`, :data:`MIN_PERIOD_SECS`),
            a missing or unreadable :data:`ExistingFile`, or the class's own check; it
            names the field, what is allowed and the value.
    """
    values = dict(values or {})
    _unknown_keys(cls, values, "")
    check_finite(values)
    try:
        built = msgspec.convert(values, cls, strict=False)
    except (msgspec.ValidationError, ValueError, TypeError) as err:
        raise rewrite(err, cls, values) from err
    _check_fields(cls, built, "")
    return built


# -- what a params class takes, for ``launch.py nodes IMPL`` -------------------------------------

_UNITS = (
    ("_m_per_s", "m/s"),
    ("_force_n", "N"),
    ("_secs", "s"),
    ("_nanos", "ns"),
    ("_hz", "Hz"),
    ("_pa", "Pa"),
    ("_mm", "mm"),
    ("_m", "m"),
    ("_px", "px"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_bytes", "bytes"),
)
_PROBES: dict[type, tuple[Any, ...]] = {int: (-(10**9), 10**9), float: (-1e9, 1e9), str: ("?",)}


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


def unit_of(name: str) -> str:
    """The unit a field's name carries (``grasp_width_m`` -> ``m``), or ``""``."""
    return next((unit for suffix, unit in _UNITS if name.endswith(suffix)), "")


def _type_text(hint: Any) -> str:
    if typing.get_origin(hint) is Annotated:
        args = typing.get_args(hint)
        return ("path of an existing file" if MUST_EXIST in args[1:] else "") or _type_text(args[0])
    if isinstance(hint, type):
        return hint.__name__
    return str(hint).replace("typing.", "")


def _attribute_docs(cls: type[Any]) -> dict[str, str]:
    """``name: text`` entries of the Google-style ``Attributes:`` sections of ``cls``'s MRO."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        lines = (klass.__doc__ or "").splitlines()
        inside, name = False, ""
        for line in lines:
            stripped = line.strip()
            if stripped == "Attributes:":
                inside = True
                continue
            if not inside:
                continue
            entry = re.match(r"^([A-Za-z_][\w, ]*):\s*(.*)$", stripped)
            if entry and line.startswith(" " * 8) and not line.startswith(" " * 9):
                name = entry[1]
                for each in name.split(","):
                    docs[each.strip()] = entry[2]
            elif stripped and name:
                for each in name.split(","):
                    docs[each.strip()] += " " + stripped
            elif not stripped and name:
                inside, name = False, ""
    return docs


def _probe(cls: type[Any], name: str, kind: type) -> tuple[str, ...]:
    """The limits the class's own check states for ``name``, found by trying far-out values.

    Required string fields get a placeholder, so that a class with a required path still
    reaches its other checks.
    """
    hints = field_hints(cls)
    base: dict[str, Any] = {
        f.name: "?"
        for f in dataclasses.fields(cls)
        if _default(f) is dataclasses.MISSING and _base_type(hints[f.name]) is str
    }
    rules: list[str] = []
    for value in _PROBES[kind]:
        values = {**base, name: value}
        try:
            msgspec.convert(values, cls, strict=False)
        except (msgspec.ValidationError, ValueError, TypeError) as err:
            found = rewrite(err, cls, values)
            if found.path == name and found.rule.startswith("must be "):
                rule = found.rule.removeprefix("must be ")
                if rule not in rules:
                    rules.append(rule)
    return tuple(rules)


def _base_type(hint: Any) -> Any:
    """``int`` for ``int``, ``int | None`` and ``Annotated[int, ...]``; None for other unions."""
    if typing.get_origin(hint) is Annotated:
        hint = typing.get_args(hint)[0]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(hint) if a is not type(None)]
        return options[0] if len(options) == 1 else None
    return hint


def describe(cls: type[Any], prefix: str = "") -> list[ParamInfo]:
    """Every parameter of ``cls``, nested ones as dotted paths, with default, unit and limits."""
    hints = field_hints(cls)
    docs = _attribute_docs(cls)
    out: list[ParamInfo] = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        nested = _dataclass_of(hint)
        if nested is not None:
            out += describe(nested, f"{prefix}{f.name}.")
            continue
        kind = _base_type(hint)
        default = _default(f)
        out.append(
            ParamInfo(
                path=f"{prefix}{f.name}",
                type=_type_text(hint),
                default=REQUIRED if default is dataclasses.MISSING else default,
                unit=unit_of(f.name),
                limits=_probe(cls, f.name, kind) if kind in _PROBES else (),
                doc=docs.get(f.name, ""),
            )
        )
    return out
