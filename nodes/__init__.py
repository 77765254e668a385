"""Node implementations, one module (or small package) per node kind.

:func:`import_all` imports every submodule so each ``@register`` runs and the launcher
can list and resolve every implementation by name. Node processes import only the
module of their own class (the launcher passes ``module:Class``), so a small node
does not pay for torch or CasADi at start-up.
"""

from __future__ import annotations

import importlib
import pkgutil


def import_all() -> None:
    """Import every node module of this package (registers their implementations)."""
    for module in pkgutil.walk_packages(__path__, prefix=f"{__name__}."):
        importlib.import_module(module.name)
