"""Node implementations, one module (or small package) per node kind.

Importing this package is cheap: it hands the registry an index of every
``@register("name")`` in its modules, read from their source text, so the
launcher can resolve a name by importing that one module, and ``--help``, ``bag info``
and ``--check`` never pay for torch or CasADi in a module the graph does not use.
Node processes import only the module of their own class (the launcher passes
``module:Class``). :func:`import_all` imports every module (``launch.py nodes``).
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

from runtime import registry

_ROOT = Path(__file__).resolve().parent
# ``@register("name")`` and its class, other decorators between them allowed.
_REGISTER = re.compile(
    r"^@register\(\s*[\"']([^\"']+)[\"']\s*\)\s*\n(?:@.*\n)*class\s+(\w+)", re.MULTILINE
)


def _module_name(path: Path) -> str:
    parts = path.relative_to(_ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def index() -> dict[str, str]:
    """``{name: "module:Class"}`` for every registered implementation, without imports."""
    out: dict[str, str] = {}
    for path in sorted(_ROOT.rglob("*.py")):
        if path.parent != _ROOT and not (path.parent / "__init__.py").exists():
            continue
        source = path.read_text(encoding="utf-8")
        if "register(" not in source:
            continue
        module = _module_name(path)
        for name, cls in _REGISTER.findall(source):
            out[name] = f"{module}:{cls}"
    return out


def import_all() -> None:
    """Import every node module of this package (registers their implementations)."""
    for path in sorted({p.split(":")[0] for p in index().values()}):
        importlib.import_module(path)


registry.add_index(index)
