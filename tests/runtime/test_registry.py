"""The registry's index of node implementations, read from source without imports."""

from __future__ import annotations

import pytest

import nodes
from runtime import registry


def test_the_index_names_every_registered_implementation() -> None:
    """The index read from source must match what importing every module registers."""
    nodes.import_all()
    index = nodes.index()
    registered = {name: registry.class_path(cls) for name, cls in registry._REGISTRY.items()}
    assert {n: p for n, p in registered.items() if p.startswith("nodes.")} == index


def test_an_unknown_name_lists_the_valid_ones() -> None:
    with pytest.raises(KeyError, match="valid: .*grasp_monitor"):
        registry.resolve("no_such.node")


def test_resolving_a_name_imports_only_its_module() -> None:
    import subprocess
    import sys

    probe = (
        "import sys, nodes; from runtime.registry import resolve; resolve('grasp_monitor'); "
        "print(sorted(m for m in sys.modules if m.startswith('nodes.')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['nodes.grasp_monitor']"
