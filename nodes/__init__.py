"""Node implementations, one module (or small package) per node kind.

Importing this package imports every submodule, so each ``@register`` runs and the
launcher can list and resolve every implementation.
"""

from __future__ import annotations

import importlib
import pkgutil

for _module in pkgutil.walk_packages(__path__, prefix=f"{__name__}."):
    importlib.import_module(_module.name)
