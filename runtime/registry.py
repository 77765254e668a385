"""Node implementations by name: ``@register("pose_estimator.ipopt")``.

A class registers itself when its module is imported. So that nothing imports every
node module to find one name, a package of nodes also hands the registry an *index*
(:func:`add_index`): a function returning ``{name: "module:Class"}``, read from the
source without importing it. :func:`resolve` imports only the module of the name it
is asked for. A graph may also name any class as ``module:Class``.
"""

from __future__ import annotations

import difflib
import importlib
import re
from collections.abc import Callable

from runtime.node import Node

_REGISTRY: dict[str, type[Node]] = {}
_INDEXES: list[Callable[[], dict[str, str]]] = []
_INDEX: dict[str, str] = {}
# ``package.module:Class``: a dotted module name, never a file path (``./x.py:C``).
_CLASS_PATH = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")


def register(name: str) -> Callable[[type[Node]], type[Node]]:
    """Class decorator: make a Node subclass available to graphs under ``name``."""

    def wrap(cls: type[Node]) -> type[Node]:
        if not (isinstance(cls, type) and issubclass(cls, Node)):
            raise TypeError(f"@register({name!r}) must decorate a Node subclass")
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise TypeError(f"node implementation {name!r} registered twice")
        cls.check_declaration()
        _REGISTRY[name] = cls
        return cls

    return wrap


def add_index(index: Callable[[], dict[str, str]]) -> None:
    """Add a source of ``{name: "module:Class"}`` for names not imported yet (read lazily)."""
    _INDEXES.append(index)


def _index() -> dict[str, str]:
    while _INDEXES:
        _INDEX.update(_INDEXES.pop(0)())
    return _INDEX


def known() -> list[str]:
    """Every implementation name, registered or indexed, sorted."""
    return sorted(set(_REGISTRY) | set(_index()))


def class_path(cls: type[Node]) -> str:
    """``module:Class`` for a node class, how a child process finds it."""
    return f"{cls.__module__}:{cls.__qualname__}"


def _import_class(impl: str) -> type[Node]:
    if not _CLASS_PATH.fullmatch(impl):
        raise KeyError(
            f"{impl[:200]!r} is not module:Class (a dotted Python module name, then a "
            "class name; not a file path)"
        )
    module_name, _, attr = impl.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise KeyError(f"cannot import module {module_name!r} for {impl!r}: {err}") from err
    cls: object = module
    for part in attr.split("."):
        cls = getattr(cls, part, None)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise KeyError(f"{impl!r} is not a Node subclass")
    return cls


def resolve(impl: str) -> type[Node]:
    """A registered name or ``module:Class`` to the node class.

    Imports at most the one module that defines it.

    Raises:
        KeyError: unknown name (the message lists the valid ones) or a bad ``module:Class``.
    """
    if impl in _REGISTRY:
        return _REGISTRY[impl]
    path = _index().get(impl)
    if path is not None:
        cls = _import_class(path)
        if _REGISTRY.get(impl) is not cls:
            raise KeyError(f"{path} does not register itself as {impl!r}")
        return cls
    if ":" in impl:
        return _import_class(impl)
    hint = "" if _INDEX else " (no index of node modules: 'import nodes' first)"
    names = known()
    close = difflib.get_close_matches(impl, names, n=3, cutoff=0.75)
    if close:
        raise KeyError(
            f"unknown implementation {impl!r}; did you mean {' or '.join(close)}? "
            f"(`launch.py nodes` lists all {len(names)})"
        )
    raise KeyError(f"unknown implementation {impl!r}; valid: {', '.join(names) or '(none)'}{hint}")
