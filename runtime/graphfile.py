"""Graph files as plain data: safe YAML reading and the command line's overrides.

``--set NODE.PARAM=VALUE`` (``PARAM`` may be a dotted path into nested parameters:
``shear.farneback.winsize=45``), ``--swap NODE=IMPL`` and ``--only NODE,NODE`` change a
copy of the document; :func:`runtime.graph.check` then checks the result.
"""

from __future__ import annotations

import copy
import inspect
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from messages.errors import GraphError
from messages.files import MAX_DEPTH, load_yaml, read_text


def parse_yaml(text: str, source: str) -> Any:
    """YAML text to Python data, safely and within bounds (:mod:`messages.files`); a syntax
    error, a duplicate key or a bound exceeded raises GraphError."""
    try:
        return load_yaml(text)
    except yaml.YAMLError as err:
        raise GraphError(f"{source}: YAML error: {err}") from err


def load_document(path: str | Path) -> dict[str, Any]:
    """Read a graph file into a plain dict (not yet checked)."""
    path = Path(path)
    try:
        text = read_text(path)
    except (OSError, ValueError) as err:
        why = err.strerror if isinstance(err, OSError) else str(err)
        raise GraphError(f"{path}: cannot read graph file: {why}") from err
    doc = parse_yaml(text, str(path))
    if not isinstance(doc, dict):
        raise GraphError(f"{path}: a graph file must be a mapping with a 'nodes' key")
    return anchor_paths(doc, path)


def anchor_paths(doc: dict[str, Any], path: Path) -> dict[str, Any]:
    """``doc`` (read from ``path``) with the relative file paths of its nodes' parameters
    found from the graph file: in its folder or the nearest folder above it that has them
    (``graphs/sort.yaml`` names ``scenes/sort_task.yaml`` of the folder above), so a graph
    runs from any working directory. A relative default of a node class (a shipped model
    or calibration) is found from the class's own folder and above when the working
    directory lacks it. A node whose implementation or parameters are not valid is left
    as it is: the check reports it."""
    from runtime.params import anchor_files
    from runtime.registry import resolve

    nodes = doc.get("nodes")
    if not isinstance(nodes, dict):
        return doc
    folder = path.resolve().parent
    folders = [folder, *folder.parents]
    for body in nodes.values():
        params = body.get("params") if isinstance(body, dict) else None
        if params is None and isinstance(body, dict):
            params = {}  # its defaults may still need finding
        if not isinstance(params, dict):
            continue
        try:
            cls = resolve(str(body.get("impl")))
            shipped = Path(inspect.getfile(cls)).resolve().parents
            anchored = anchor_files(cls.Params, params, folders, shipped)
        except (KeyError, TypeError, ImportError):
            continue
        if anchored != params or "params" in body:
            body["params"] = anchored
    return doc


def _set(nodes: dict[str, Any], item: str, source: str) -> None:
    target, sep, value = item.partition("=")
    name, dot, param = target.partition(".")
    keys = param.split(".")
    if len(keys) > MAX_DEPTH:
        raise GraphError(
            f"{source}: --set {item[:60]!r}: a PARAM path of more than {MAX_DEPTH} keys"
        )
    if not sep or not dot or not all(keys) or name not in nodes:
        raise GraphError(
            f"{source}: --set {item!r}: expected NODE.PARAM=VALUE (PARAM may be a dotted "
            f"path: shear.farneback.winsize=45) with a node of the graph ({', '.join(nodes)})"
        )
    if not isinstance(nodes[name], dict):
        raise GraphError(f"{source}: --set {item!r}: node {name!r} is not a mapping")
    params = nodes[name].get("params")
    if params is None:
        params = nodes[name]["params"] = {}
    where = f"{name}.params"
    for key in keys[:-1]:
        if not isinstance(params, dict):
            raise GraphError(f"{source}: --set {item!r}: {where} is not a mapping")
        where += f".{key}"
        params = params.setdefault(key, {})
    if not isinstance(params, dict):
        raise GraphError(f"{source}: --set {item!r}: {where} is not a mapping")
    params[keys[-1]] = parse_yaml(value, f"--set {item}")


def apply_overrides(
    doc: dict[str, Any],
    *,
    sets: Sequence[str] = (),
    swaps: Sequence[str] = (),
    only: Sequence[str] = (),
    source: str = "<graph>",
) -> dict[str, Any]:
    """Return a copy of ``doc`` with ``--set node.param=value``, ``--swap node=impl`` and
    ``--only a,b`` applied. Values of ``--set`` are parsed as YAML (``3``, ``true``, ``[1, 2]``);
    its parameter may be a dotted path into nested parameters (``shear.farneback.winsize``).
    """
    doc = copy.deepcopy(doc)
    nodes = doc.get("nodes")
    if not isinstance(nodes, dict):
        nodes = {}
    for item in swaps:
        name, sep, impl = item.partition("=")
        if not sep or not impl or name not in nodes or not isinstance(nodes[name], dict):
            raise GraphError(
                f"{source}: --swap {item!r}: expected NODE=IMPL with a node of the graph "
                f"({', '.join(nodes)})"
            )
        nodes[name]["impl"] = impl
    for item in sets:
        _set(nodes, item, source)
    if only:
        keep = set(only)
        unknown = keep - set(nodes)
        if unknown:
            raise GraphError(f"{source}: --only names unknown node(s) {sorted(unknown)}")
        for name in list(nodes):
            if name not in keep:
                del nodes[name]
        for spec in nodes.values():
            inputs = spec.get("inputs") if isinstance(spec, dict) else None
            if not isinstance(inputs, dict):
                continue  # the checker reports it
            for port, ref in list(inputs.items()):
                topic = ref.get("from") if isinstance(ref, dict) else ref
                if isinstance(topic, str) and topic.partition("/")[0] not in keep:
                    del inputs[port]
    return doc
