"""Typed node parameters from plain mappings (YAML, ``--set``).

Parameter classes are frozen, keyword-only dataclasses that check their own values in
``__post_init__`` and raise ``ValueError`` naming the field. This module adds the
checks every class shares: unknown keys and wrong types, via msgspec.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import msgspec


def build_params(cls: type[Any], values: Mapping[str, Any] | None) -> Any:
    """Build ``cls`` from ``values``.

    Raises:
        ValueError: an unknown key, a value of the wrong type, or the class's own check;
            the message names the field.
    """
    values = dict(values or {})
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}; valid: {sorted(names)}")
    try:
        return msgspec.convert(values, cls, strict=False)
    except msgspec.ValidationError as err:
        raise ValueError(str(err)) from err
