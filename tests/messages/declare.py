"""Throwaway message types for the tests (use with the ``scratch_registry`` fixture)."""

from __future__ import annotations

from typing import Any

import msgspec

from messages.base import Message


def declare(name: str, fields: list[tuple[str, Any]], *, keep: bool = False) -> type[Message]:
    """Declare a message type; unless ``keep``, take it back out of the registry so the
    same name can be declared again with other fields."""
    cls = msgspec.defstruct(name, fields, bases=(Message,), kw_only=True, module=__name__)
    if not keep:
        del Message.registry[name]
    return cls
