"""Typed message classes, their array fields, fingerprints and schema descriptions.

A message is a ``msgspec.Struct`` (keyword-only) whose fields are scalars, strings,
lists of those, nested structs (the :class:`Header`), or numpy arrays declared with
:func:`array_field`-style annotations::

    class ToFImage(Message):
        header: Header
        depth_m: Annotated[np.ndarray, Array("float32", (None, None))]

Arrays travel as raw buffers next to the MessagePack header (see ``codec``); the rest
is validated by msgspec on decode. The fingerprint is a hash of the type name and
every field's name and type, so adding, removing, renaming or retyping a field
changes it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import operator
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import msgspec
import numpy as np


@dataclass(frozen=True)
class Array:
    """Declares an ndarray field: its dtype and shape (``None`` = any length on that axis)."""

    dtype: str
    shape: tuple[int | None, ...]

    def check(self, type_name: str, field: str, value: np.ndarray) -> None:
        """Raise ``ValueError`` naming the field if ``value`` does not fit this declaration."""
        if not isinstance(value, np.ndarray):
            raise ValueError(f"{type_name}.{field}: expected ndarray, got {type(value).__name__}")
        if value.dtype.newbyteorder("=") != np.dtype(self.dtype).newbyteorder("="):
            raise ValueError(f"{type_name}.{field}: dtype must be {self.dtype}, got {value.dtype}")
        if value.ndim != len(self.shape):
            raise ValueError(
                f"{type_name}.{field}: expected {len(self.shape)} dimensions, got shape {value.shape}"
            )
        for axis, (want, got) in enumerate(zip(self.shape, value.shape, strict=True)):
            if want is not None and want != got:
                raise ValueError(
                    f"{type_name}.{field}: axis {axis} must have length {want}, got shape {value.shape}"
                )


class Header(msgspec.Struct, kw_only=True):
    """Stamp (nanoseconds since the epoch, or scene time), per-output sequence, frame id."""

    stamp_nanos: int = 0
    seq: int = 0
    frame_id: str = ""


@dataclass(frozen=True)
class Schema:
    """What the codec needs to know of a message type, computed once per class."""

    array_fields: dict[str, Array]
    fingerprint: str
    description: dict[str, Any]


class Message(msgspec.Struct, kw_only=True):
    """Base of every message type. Subclasses register themselves by class name."""

    registry: ClassVar[dict[str, type[Message]]] = {}
    # Fields that are finite by meaning: a NaN pressure is a broken sensor, not a reading.
    # The runtime counts received messages that break this (``nonfinite``) and warns once.
    # In an array named in ``nan_marks_invalid`` a NaN is an invalid element (a depth
    # pixel without a return), so only infinities break it.
    finite_fields: ClassVar[tuple[str, ...]] = ()
    nan_marks_invalid: ClassVar[frozenset[str]] = frozenset()
    # Fields that measure the machine, not the data (a solve time): two runs of the same
    # input differ there by nature, so ``bag diff`` does not compare them.
    wall_clock_fields: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        name = cls.__name__
        if name in Message.registry:
            raise TypeError(f"message type {name} is declared twice")
        Message.registry[name] = cls

    @classmethod
    def schema(cls) -> Schema:
        """The type's array declarations, fingerprint and description (cached)."""
        return _schema(cls)

    @classmethod
    def finite_check(cls) -> Callable[[Message], bool] | None:
        """The question a publisher asks of every message of this class: whether each of
        its ``finite_fields`` is finite (NaN allowed where ``nan_marks_invalid`` says), one
        callable made once per class; None for a class without such fields.
        :meth:`nonfinite_fields` names the fields of a message it says no to."""
        checks = _finite_checks(cls)
        return checks.all_finite if checks.fields else None

    def nonfinite_fields(self) -> list[str]:
        """The names of ``finite_fields`` that hold NaN or infinity (see above)."""
        # The publisher runs this on every message (runtime/zmqio.py): one question for
        # all the fields first, the field-by-field pass only for a message that fails it.
        checks = _finite_checks(type(self))
        if checks.all_finite(self):
            return []
        return [name for name, nan_ok in checks.fields if not _finite(getattr(self, name), nan_ok)]

    def validate(self) -> None:
        """Check every array field against its declaration (raises ``ValueError``)."""
        for name, spec in self.schema().array_fields.items():
            spec.check(type(self).__name__, name, getattr(self, name))


def _finite(value: Any, nan_ok: bool) -> bool:
    """Whether ``value`` (an array or a number) holds no infinity, nor NaN unless ``nan_ok``."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iub" or not value.size:  # never NaN or infinite
            return True
        # One pass and one temporary over a float array. argmax/argmin find a True/False in
        # a bool array about twice as fast as any()/all() (0.85 against 1.8 us on a 172 x
        # 224 image); ravel("K") flattens the ufunc's contiguous result, whatever its
        # order, without a copy.
        if nan_ok:
            inf = np.isinf(value).ravel("K")
            return not inf[inf.argmax()]
        finite = np.isfinite(value).ravel("K")
        return bool(finite[finite.argmin()])
    return math.isfinite(value)


@dataclass(frozen=True, slots=True)
class _FiniteChecks:
    """A message class's finite fields, computed once: each with whether a NaN is allowed
    there; those declared as arrays; and a getter of the others (the numbers), which
    answers a tuple where there are several and the number itself where there is one."""

    fields: tuple[tuple[str, bool], ...]
    arrays: tuple[tuple[str, bool], ...]
    numbers: Callable[[Any], Any] | None
    several: bool

    def all_finite(self, msg: Message) -> bool:
        """Whether every finite field of ``msg`` is: each array by its pass, the numbers by
        their sum. A sum of finite numbers is finite unless it overflows, and a NaN or an
        infinity makes it NaN or infinite (or, in ``math.fsum``, raises), so a finite sum
        means every number is; an overflow only sends the message to the field-by-field
        pass, which then finds no field."""
        for name, nan_ok in self.arrays:
            value = getattr(msg, name)
            if type(value) is np.ndarray and nan_ok and value.dtype.kind == "f" and value.size:
                # _finite's pass for a float image with NaN pixels (a depth image), without
                # its call and type questions: this runs for every frame a camera publishes.
                inf = np.isinf(value).ravel("K")
                if inf[inf.argmax()]:
                    return False
            elif not _finite(value, nan_ok):
                return False
        if self.numbers is None:
            return True
        values = self.numbers(msg)
        try:
            # fsum turns each into a double (no numpy overflow warning) and sums exactly.
            return math.isfinite(math.fsum(values) if self.several else values)
        except (TypeError, ValueError, OverflowError):  # not numbers, inf - inf, overflow
            return False


@functools.cache
def _finite_checks(cls: type[Message]) -> _FiniteChecks:
    """``cls``'s finite fields and how to check them (computed once)."""
    fields = tuple((name, name in cls.nan_marks_invalid) for name in cls.finite_fields)
    declared = cls.schema().array_fields
    numbers = [name for name, _ in fields if name not in declared]
    return _FiniteChecks(
        fields=fields,
        arrays=tuple(f for f in fields if f[0] in declared),
        numbers=operator.attrgetter(*numbers) if numbers else None,
        several=len(numbers) > 1,
    )


@functools.cache
def _schema(cls: type[Message]) -> Schema:
    hints = typing.get_type_hints(cls, include_extras=True)
    arrays = {}
    for field in msgspec.structs.fields(cls):
        spec = _array_spec(hints[field.name])
        if spec is not None:
            arrays[field.name] = spec
    description = describe(cls)
    return Schema(
        array_fields=arrays, fingerprint=fingerprint_of(description), description=description
    )


def fingerprint_of(description: dict[str, Any]) -> str:
    """The fingerprint of a type description (:func:`describe`): 16 hex digits of its hash."""
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]


def _array_spec(hint: Any) -> Array | None:
    if typing.get_origin(hint) is typing.Annotated:
        for meta in hint.__metadata__:
            if isinstance(meta, Array):
                return meta
    return None


def describe_type(hint: Any) -> Any:
    """A field's type as JSON: a name, ``{"array": ...}``, ``{"struct": ...}`` or ``{"generic": ...}``."""
    spec = _array_spec(hint)
    if spec is not None:
        return {"array": {"dtype": np.dtype(spec.dtype).str, "shape": list(spec.shape)}}
    if isinstance(hint, type) and issubclass(hint, msgspec.Struct):
        hints = typing.get_type_hints(hint)
        out: dict[str, Any] = {
            "struct": hint.__name__,
            "fields": [
                [f.name, describe_type(hints[f.name])] for f in msgspec.structs.fields(hint)
            ],
        }
        config = hint.__struct_config__
        if config.tag is not None:  # one of a tagged union: the wire names it so
            out["tag"] = [config.tag_field, config.tag]
        return out
    origin = typing.get_origin(hint)
    if origin is not None:
        return {
            "generic": getattr(origin, "__name__", str(origin)),
            "args": [describe_type(a) for a in typing.get_args(hint)],
        }
    return getattr(hint, "__name__", repr(hint))


def describe(cls: type[msgspec.Struct]) -> dict[str, Any]:
    """A JSON-able description of a message type: its name and every field's type.

    Bags store this next to each channel so a reader can decode old files without the
    project's classes of that day.
    """
    hints = typing.get_type_hints(cls, include_extras=True)
    return {
        "type": cls.__name__,
        "fields": [[f.name, describe_type(hints[f.name])] for f in msgspec.structs.fields(cls)],
    }


def message_type(name: str) -> type[Message]:
    """Look up a message class by name (``KeyError`` lists the known ones)."""
    try:
        return Message.registry[name]
    except KeyError:
        known = ", ".join(sorted(Message.registry))
        raise KeyError(f"unknown message type {name!r}; known: {known}") from None
