"""A JSON Schema of graph files, from the node classes' parameter declarations.

An editor with a YAML language server checks a graph file against it as one types
(``launch.py schema --out graph.schema.json``, docs/graphs.md): an unknown key, a value of
the wrong type or beyond its declared limits, a node's parameters for its ``impl``. The
schema says what a declaration says; the checker (``launch.py GRAPH --check``) says
more: that edges fit, that files exist, the cross-field checks.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgspec

from runtime.graph import MAX_QUEUE_SIZE, NODE_NAME, POLICIES, RESTART_POLICIES, RestartSpec
from runtime.hosts import DEFAULTS as HOST_DEFAULTS
from runtime.hosts import HOST_POLICIES
from runtime.node import Node
from runtime.params import MAX_SECS

DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _input() -> dict[str, Any]:
    topic = {"type": "string", "pattern": "^[^/]+/[^/]+$", "description": "node/output"}
    return {
        "anyOf": [
            topic,
            {
                "type": "object",
                "required": ["from"],
                "properties": {
                    "from": topic,
                    "policy": {"enum": list(POLICIES)},
                    "queue_size": {"type": "integer", "minimum": 1, "maximum": MAX_QUEUE_SIZE},
                },
                "additionalProperties": False,
            },
        ]
    }


def graph_schema(impls: Mapping[str, type[Node]]) -> dict[str, Any]:
    """The schema of a graph file whose nodes name one of ``impls`` (registered name ->
    class) or a ``module:Class`` (its parameters then unchecked here)."""
    classes = sorted({cls.Params for cls in impls.values()} | {RestartSpec}, key=repr)
    refs, defs = msgspec.json.schema_components(classes, ref_template="#/$defs/{name}")
    ref = dict(zip(classes, refs, strict=True))
    by_impl = [
        {
            "if": {"properties": {"impl": {"const": name}}, "required": ["impl"]},
            "then": {"properties": {"params": {"anyOf": [ref[cls.Params], {"type": "null"}]}}},
        }
        for name, cls in sorted(impls.items())
    ]
    node = {
        "type": "object",
        "required": ["impl"],
        "properties": {
            "impl": {
                "anyOf": [
                    {"enum": sorted(impls)},
                    {"type": "string", "pattern": r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$"},
                ],
                "description": "a registered implementation (`launch.py nodes`) or module:Class",
            },
            "params": {"type": ["object", "null"]},
            "inputs": {"type": ["object", "null"], "additionalProperties": _input()},
            "restart": {
                "anyOf": [{"type": "null"}, {"enum": list(RESTART_POLICIES)}, ref[RestartSpec]]
            },
            "required": {"type": "boolean"},
            "host": {"type": "string"},
            "hang_timeout_secs": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_SECS},
        },
        "additionalProperties": False,
        "allOf": by_impl,
    }
    return {
        "$schema": DRAFT,
        "title": "Soft-bubble gripper graph file",
        "type": "object",
        "required": ["nodes"],
        "properties": {
            "name": {"type": "string"},
            "description": {"type": "string"},
            "hosts": {"type": "object"},
            "on_host_lost": {"enum": list(HOST_POLICIES)},
            **{key: {"type": "number"} for key in HOST_DEFAULTS if key.endswith("_secs")},
            "nodes": {
                "type": "object",
                "minProperties": 1,
                "propertyNames": {"pattern": f"^{NODE_NAME.pattern}$"},
                "additionalProperties": {"$ref": "#/$defs/node"},
            },
        },
        "additionalProperties": False,
        "$defs": {**defs, "node": node},
    }
