"""No import circles among the project's modules: each imports the other only one way.

Every import counts, wherever it stands (module level, inside a function, under
``TYPE_CHECKING``): a circle hidden by a late import is still two modules that cannot be
read, tested or moved apart. Read from the source with ``ast``; nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("messages", "runtime", "geometry", "perception", "sim", "devices", "viz", "nodes")
PACKAGES += ("cli", "bench")


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> source file, for every module of the project's packages."""
    found = {}
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The project modules that ``name`` (at ``path``) imports, itself excluded."""

    def known(dotted: str) -> str | None:  # the module itself, or the package holding it
        while dotted and dotted not in modules:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(m for a in node.names if (m := known(a.name)))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, one level up per extra dot
                base = ".".join(package[: len(package) - node.level + 1] + [base]).strip(".")
            for alias in node.names:  # `from pkg import module` imports that module
                sub = f"{base}.{alias.name}"
                if (m := sub if sub in modules else known(base)) is not None:
                    out.add(m)
    out.discard(name)
    return out


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_the_finder_sees_a_circle_through_late_and_type_checking_imports(
    tmp_path: Path,
) -> None:
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "__init__.py").write_text("")
    (tmp_path / "bench" / "a.py").write_text("def f():\n    from bench import b\n")
    (tmp_path / "bench" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bench.a import f\n"
    )
    (tmp_path / "bench" / "c.py").write_text("from . import a\n")
    modules = project_modules(tmp_path)
    edges = {name: imports_of(name, path, modules) for name, path in modules.items()}
    assert edges["bench.c"] == {"bench.a"}
    assert circles(edges) == [["bench.a", "bench.b"]]


def test_no_import_circles_among_project_modules() -> None:
    modules = project_modules()
    assert {"runtime.bag.reader", "bench.report", "cli.main"} <= set(modules)
    edges = {name: imports_of(name, path, modules) for name, path in modules.items()}
    assert circles(edges) == [], "modules that import each other (break the circle)"
