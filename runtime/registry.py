"""Node implementations by name: ``@register("pose_estimator.ipopt")``.

The ``nodes`` package registers its implementations on import; ``launch.py`` imports
it. A graph may also name any class as ``module:Class``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from runtime.node import Node

_REGISTRY: dict[str, type[Node]] = {}


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


def known() -> list[str]:
    """Every registered implementation name, sorted."""
    return sorted(_REGISTRY)


def class_path(cls: type[Node]) -> str:
    """``module:Class`` for a node class, how a child process finds it."""
    return f"{cls.__module__}:{cls.__qualname__}"


def resolve(impl: str) -> type[Node]:
    """A registered name or ``module:Class`` to the node class.

    Raises:
        KeyError: unknown name (the message lists the valid ones) or a bad ``module:Class``.
    """
    if impl in _REGISTRY:
        return _REGISTRY[impl]
    if ":" in impl:
        module_name, _, attr = impl.partition(":")
        try:
            module = importlib.import_module(module_name)
        except ImportError as err:
            raise KeyError(f"cannot import module {module_name!r} for {impl!r}: {err}") from err
        cls = getattr(module, attr, None)
        if not (isinstance(cls, type) and issubclass(cls, Node)):
            raise KeyError(f"{impl!r} is not a Node subclass")
        return cls
    raise KeyError(f"unknown implementation {impl!r}; valid: {', '.join(known()) or '(none)'}")
