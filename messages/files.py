"""Reading the project's YAML files (graphs, scenes) within bounds, before anything walks them.

A file is read only if it is a regular file of at most :data:`MAX_FILE_BYTES` (a device
such as ``/dev/zero`` or a FIFO would never end, or never start). Its YAML is parsed with
``safe_load``'s constructors, duplicate mapping keys refused, and composed within bounds
checked while it is composed, before any Python value exists: at most :data:`MAX_DEPTH`
levels of nesting, :data:`MAX_ALIASES` aliases and :data:`MAX_NODES` values once every
alias is expanded (an "alias bomb" of a few hundred bytes expands to billions), and no
integer of more than :data:`MAX_INT_DIGITS` digits. Every refusal is a
``yaml.YAMLError`` naming the line and column, so callers' YAML errors cover it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml

MAX_FILE_BYTES = 1 << 20  # 1 MiB: the largest graph or scene of the project is 6 kB
MAX_DEPTH = 64  # levels of nesting (the deepest parameters nest 4)
MAX_NODES = 100_000  # values once aliases are expanded
MAX_ALIASES = 1_000
MAX_INT_DIGITS = 40  # any integer beyond 64 bits is refused later; this bounds the parse


class _BoundedLoader(yaml.SafeLoader):  # type: ignore[misc]
    """``safe_load`` with duplicate keys refused and the bounds of the module docstring."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0
        self._aliases = 0
        self._sizes: dict[str, int] = {}  # anchor -> values under it, aliases expanded

    def _refuse(self, what: str, mark: Any) -> None:
        raise yaml.composer.ComposerError(None, None, what, mark)

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            self._nodes += self._sizes.get(event.anchor, 1)
            if self._aliases > MAX_ALIASES:
                self._refuse(f"more than {MAX_ALIASES} aliases", event.start_mark)
            if self._nodes > MAX_NODES:
                self._refuse(
                    f"more than {MAX_NODES} values once its aliases are expanded",
                    event.start_mark,
                )
            return super().compose_node(parent, index)
        self._depth += 1
        self._nodes += 1
        if self._depth > MAX_DEPTH:
            self._refuse(f"nested more than {MAX_DEPTH} levels deep", event.start_mark)
        if self._nodes > MAX_NODES:
            self._refuse(f"more than {MAX_NODES} values", event.start_mark)
        start = self._nodes - 1
        node = super().compose_node(parent, index)
        self._depth -= 1
        anchor = getattr(event, "anchor", None)
        if anchor is not None:
            self._sizes[anchor] = self._nodes - start
        return node


def _construct_mapping(loader: _BoundedLoader, node: yaml.MappingNode, deep: bool = False) -> Any:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # an unhashable key (a list): the constructor says so
            break
        if duplicate:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
    return loader.construct_mapping(node, deep)


def _construct_int(loader: _BoundedLoader, node: yaml.ScalarNode) -> Any:
    digits = sum(c.isdigit() for c in str(node.value))
    if digits > MAX_INT_DIGITS:
        raise yaml.constructor.ConstructorError(
            None, None, f"an integer of {digits} digits (at most {MAX_INT_DIGITS})", node.start_mark
        )
    return loader.construct_yaml_int(node)


_BoundedLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_BoundedLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)


def load_yaml(text: str) -> Any:
    """YAML text to Python data, safely and within bounds.

    Raises:
        yaml.YAMLError: bad YAML, a duplicate key, or a bound exceeded (line and column named).
    """
    return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 - a SafeLoader subclass


def read_text(path: str | Path, limit: int = MAX_FILE_BYTES) -> str:
    """The text of a regular file of at most ``limit`` bytes.

    Raises:
        OSError: it cannot be opened (missing, a name too long, permission).
        ValueError: not a regular file, larger than ``limit``, or not UTF-8 (the message
            says which).
    """
    # O_NONBLOCK: opening a FIFO must not wait for a writer; a regular file ignores it.
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = "a directory" if stat.S_ISDIR(mode) else "a device, FIFO or socket"
            raise ValueError(f"not a regular file ({kind})")
        data = f.read(limit + 1)
    if len(data) > limit:
        raise ValueError(f"larger than {limit} bytes")
    try:
        return data.decode()
    except UnicodeDecodeError as err:
        raise ValueError(f"not UTF-8 text ({err.reason} at byte {err.start})") from err
