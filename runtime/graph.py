"""Graph files: load, apply command-line overrides, and check before anything starts.

A graph file (YAML, read with a duplicate-key-refusing ``safe_load``)::

    nodes:
      contact_patch: {impl: contact_patch, inputs: {left: left_camera/image, ...}}
      pose:
        impl: pose_estimator.ipopt            # registered name, or module:Class
        params: {object: mug, max_points: 4000}
        inputs: {patch: {from: contact_patch/patch, policy: latest}}
        restart: {policy: on-failure, max_restarts: 3, backoff_secs: 0.5}
        required: true                        # a final crash stops the graph
        host: 127.0.0.1                       # tcp on this address; ipc otherwise

The checker collects every error (unknown implementation, unknown output, edge type
mismatch, missing required input, unknown or ill-typed parameter, duplicate name,
YAML syntax) and raises one :class:`GraphError` whose lines each name the file, the
node and the field.
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from messages.base import Message
from messages.errors import GraphError
from runtime.node import Node
from runtime.params import build_params
from runtime.registry import resolve

POLICIES = ("queue", "latest")
RESTART_POLICIES = ("never", "on-failure")
NODE_KEYS = {"impl", "params", "inputs", "restart", "required", "host", "hang_timeout_secs"}
TOP_KEYS = {"nodes", "name", "description"}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")


@dataclass(frozen=True)
class InputSpec:
    """One edge into a node: the topic it reads and how it queues."""

    port: str
    topic: str
    policy: str = "queue"
    queue_size: int = 1000


@dataclass(frozen=True)
class RestartSpec:
    """What the supervisor does when a node dies or stops answering."""

    policy: str = "never"
    max_restarts: int = 5
    backoff_secs: float = 0.5
    backoff_max_secs: float = 8.0


@dataclass
class NodeSpec:
    """A checked node: its class, built parameters, resolved ports and topics."""

    name: str
    impl: str
    cls: type[Node]
    params: Any
    raw_params: dict[str, Any]
    inputs: dict[str, InputSpec]
    input_types: dict[str, type[Message]]
    outputs: dict[str, type[Message]]
    restart: RestartSpec = field(default_factory=RestartSpec)
    required: bool = True
    host: str | None = None
    hang_timeout_secs: float = 30.0

    def topic(self, output: str) -> str:
        """The wire topic of an output: verbatim if it contains '/', else ``node/output``."""
        return output if "/" in output else f"{self.name}/{output}"

    @property
    def topics(self) -> dict[str, str]:
        return {output: self.topic(output) for output in self.outputs}


@dataclass
class Graph:
    """A checked graph, ready to launch."""

    source: str
    nodes: dict[str, NodeSpec]
    document: dict[str, Any]

    def providers(self) -> dict[str, tuple[str, type[Message]]]:
        """Topic -> (publishing node, message type)."""
        return {
            spec.topic(out): (spec.name, kind)
            for spec in self.nodes.values()
            for out, kind in spec.outputs.items()
        }

    def edges(self) -> list[tuple[str, str, str]]:
        """(topic, subscribing node, port) for every input of every node."""
        return [
            (inp.topic, spec.name, inp.port)
            for spec in self.nodes.values()
            for inp in spec.inputs.values()
        ]

    def barrier_topics(self) -> set[str]:
        """Topics from which a message can reach a node that merges several publishers.

        A node reading the topics of two or more publishers (a fan-in) sees their
        messages in an order set by timing; one reading a single publisher sees them in
        the order they were published, however many topics it reads (lockstep gives each
        publisher one socket per subscriber, and ZeroMQ keeps one connection's order).
        Lockstep replay waits for the graph to be idle before a message on a barrier
        topic and pipelines the others. Nodes with ``merges_in_any_order`` (the recorder)
        do not count as fan-ins.
        """
        providers = {topic: node for topic, (node, _) in self.providers().items()}
        readers: dict[str, set[str]] = defaultdict(set)
        for topic, node, _ in self.edges():
            readers[topic].add(node)
        fan_ins = {
            spec.name
            for spec in self.nodes.values()
            if not spec.cls.merges_in_any_order
            and len({providers.get(inp.topic) for inp in spec.inputs.values()}) > 1
        }
        barriers = set()
        for start in providers:
            seen: set[str] = set()
            todo = [start]
            while todo:
                topic = todo.pop()
                for node in readers[topic] - seen:
                    seen.add(node)
                    todo.extend(self.nodes[node].topics.values())
            if seen & fan_ins:
                barriers.add(start)
        return barriers


class _UniqueKeyLoader(yaml.SafeLoader):  # type: ignore[misc]
    """``safe_load`` that refuses duplicate mapping keys instead of keeping the last."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> Any:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def parse_yaml(text: str, source: str) -> Any:
    """YAML text to Python data, safely; a syntax error or duplicate key raises GraphError."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        raise GraphError(f"{source}: YAML error: {err}") from err


def load_document(path: str | Path) -> dict[str, Any]:
    """Read a graph file into a plain dict (not yet checked)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise GraphError(f"{path}: cannot read graph file: {err.strerror}") from err
    doc = parse_yaml(text, str(path))
    if not isinstance(doc, dict):
        raise GraphError(f"{path}: a graph file must be a mapping with a 'nodes' key")
    return doc


def apply_overrides(
    doc: dict[str, Any],
    *,
    sets: Sequence[str] = (),
    swaps: Sequence[str] = (),
    only: Sequence[str] = (),
    source: str = "<graph>",
) -> dict[str, Any]:
    """Return a copy of ``doc`` with ``--set node.param=value``, ``--swap node=impl`` and
    ``--only a,b`` applied. Values of ``--set`` are parsed as YAML (``3``, ``true``, ``[1, 2]``).
    """
    doc = yaml.safe_load(yaml.safe_dump(doc))  # a deep copy of plain data
    nodes = doc.get("nodes") or {}
    for item in swaps:
        name, sep, impl = item.partition("=")
        if not sep or name not in nodes:
            raise GraphError(
                f"{source}: --swap {item!r}: expected NODE=IMPL with a node of the graph"
            )
        nodes[name]["impl"] = impl
    for item in sets:
        target, sep, value = item.partition("=")
        name, dot, param = target.partition(".")
        if not sep or not dot or name not in nodes:
            raise GraphError(
                f"{source}: --set {item!r}: expected NODE.PARAM=VALUE with a node of the graph"
            )
        nodes[name].setdefault("params", {})
        nodes[name]["params"][param] = parse_yaml(value, f"--set {item}")
    if only:
        keep = set(only)
        unknown = keep - set(nodes)
        if unknown:
            raise GraphError(f"{source}: --only names unknown node(s) {sorted(unknown)}")
        for name in list(nodes):
            if name not in keep:
                del nodes[name]
        for spec in nodes.values():
            inputs = spec.get("inputs") or {}
            for port, ref in list(inputs.items()):
                topic = ref.get("from") if isinstance(ref, dict) else ref
                if isinstance(topic, str) and topic.partition("/")[0] not in keep:
                    del inputs[port]
    return doc


def _restart(value: Any, where: str, errors: list[str]) -> RestartSpec:
    if value is None:
        return RestartSpec()
    if isinstance(value, str):
        value = {"policy": value}
    if not isinstance(value, dict):
        errors.append(f"{where}.restart: expected a policy name or a mapping, got {value!r}")
        return RestartSpec()
    try:
        spec: RestartSpec = build_params(RestartSpec, value)
    except ValueError as err:
        errors.append(f"{where}.restart: {err}")
        return RestartSpec()
    if spec.policy not in RESTART_POLICIES:
        errors.append(
            f"{where}.restart.policy: must be one of {RESTART_POLICIES}, got {spec.policy!r}"
        )
    if spec.max_restarts < 0 or spec.backoff_secs < 0 or spec.backoff_max_secs < spec.backoff_secs:
        errors.append(
            f"{where}.restart: max_restarts >= 0 and 0 <= backoff_secs <= backoff_max_secs"
        )
    return spec


def _input(port: str, ref: Any, where: str, errors: list[str]) -> InputSpec | None:
    if isinstance(ref, str):
        ref = {"from": ref}
    if not isinstance(ref, dict) or not isinstance(ref.get("from"), str):
        errors.append(
            f"{where}.inputs.{port}: expected 'node/output' or {{from: node/output, ...}}"
        )
        return None
    unknown = set(ref) - {"from", "policy", "queue_size"}
    if unknown:
        errors.append(f"{where}.inputs.{port}: unknown key(s) {sorted(unknown)}")
    topic = ref["from"]
    if topic.count("/") != 1 or not all(topic.split("/")):
        errors.append(f"{where}.inputs.{port}: {topic!r} is not of the form node/output")
        return None
    policy = ref.get("policy", "queue")
    if policy not in POLICIES:
        errors.append(f"{where}.inputs.{port}.policy: must be one of {POLICIES}, got {policy!r}")
    size = ref.get("queue_size", 1000)
    if not isinstance(size, int) or isinstance(size, bool) or size < 1:
        errors.append(f"{where}.inputs.{port}.queue_size: must be an integer >= 1, got {size!r}")
        size = 1000
    return InputSpec(port=port, topic=topic, policy=policy, queue_size=size)


def check(doc: Mapping[str, Any], source: str = "<graph>") -> Graph:
    """Check a graph document completely; raise one GraphError listing every problem."""
    errors: list[str] = []
    if (
        not isinstance(doc, Mapping)
        or not isinstance(doc.get("nodes"), Mapping)
        or not doc["nodes"]
    ):
        raise GraphError(f"{source}: a graph needs a non-empty 'nodes' mapping")
    for key in set(doc) - TOP_KEYS:
        errors.append(f"{source}: unknown top-level key {key!r} (valid: {sorted(TOP_KEYS)})")
    specs: dict[str, NodeSpec] = {}
    raw_inputs: dict[str, dict[str, InputSpec]] = {}
    for name, body in doc["nodes"].items():
        where = f"{source}: node {name!r}"
        if not isinstance(name, str) or not _NAME.match(name):
            errors.append(f"{where}: a node name is letters, digits, '_' and '-'")
            continue
        if not isinstance(body, Mapping):
            errors.append(f"{where}: expected a mapping with 'impl'")
            continue
        for key in set(body) - NODE_KEYS:
            errors.append(f"{where}: unknown key {key!r} (valid: {sorted(NODE_KEYS)})")
        impl = body.get("impl")
        if not isinstance(impl, str):
            errors.append(f"{where}.impl: required, a registered name or module:Class")
            continue
        try:
            cls = resolve(impl)
        except KeyError as err:
            errors.append(f"{where}.impl: {err.args[0]}")
            continue
        raw_params = dict(body.get("params") or {})
        try:
            params = build_params(cls.Params, raw_params)
            inputs_decl, outputs = cls.ports(params)
        except (ValueError, TypeError) as err:
            errors.append(f"{where}.params: {err}")
            continue
        inputs: dict[str, InputSpec] = {}
        for port, ref in (body.get("inputs") or {}).items():
            if not cls.raw_input and port not in inputs_decl:
                errors.append(
                    f"{where}.inputs.{port}: {impl} has no input {port!r} (inputs: {sorted(inputs_decl)})"
                )
                continue
            parsed = _input(str(port), ref, where, errors)
            if parsed is not None:
                inputs[str(port)] = parsed
        hang = body.get("hang_timeout_secs", 30.0)
        if not isinstance(hang, int | float) or hang <= 0:
            errors.append(f"{where}.hang_timeout_secs: must be > 0, got {hang!r}")
            hang = 30.0
        host = body.get("host")
        if host is not None and not isinstance(host, str):
            errors.append(f"{where}.host: expected an address string, got {host!r}")
            host = None
        specs[name] = NodeSpec(
            name=name,
            impl=impl,
            cls=cls,
            params=params,
            raw_params=raw_params,
            inputs=inputs,
            input_types=dict(inputs_decl),
            outputs=dict(outputs),
            restart=_restart(body.get("restart"), where, errors),
            required=bool(body.get("required", True)),
            host=host,
            hang_timeout_secs=float(hang),
        )
        raw_inputs[name] = inputs
    graph = Graph(source=source, nodes=specs, document=dict(doc))
    providers: dict[str, tuple[str, type[Message]]] = {}
    for spec in specs.values():
        for out, kind in spec.outputs.items():
            topic = spec.topic(out)
            if topic in providers:
                errors.append(
                    f"{source}: node {spec.name!r}: topic {topic!r} is also published by {providers[topic][0]!r}"
                )
            providers[topic] = (spec.name, kind)
    for spec in specs.values():
        where = f"{source}: node {spec.name!r}"
        for port, inp in spec.inputs.items():
            if inp.topic not in providers:
                node, _, out = inp.topic.partition("/")
                if node in specs:
                    outs = sorted(specs[node].outputs)
                    errors.append(
                        f"{where}.inputs.{port}: node {node!r} has no output {out!r} (outputs: {outs})"
                    )
                else:
                    errors.append(f"{where}.inputs.{port}: no node publishes {inp.topic!r}")
                continue
            if spec.cls.raw_input:
                continue
            got = providers[inp.topic][1]
            want = spec.input_types[port]
            if got is not want:
                errors.append(
                    f"{where}.inputs.{port}: type mismatch: {inp.topic} carries {got.__name__}, "
                    f"{spec.impl} expects {want.__name__}"
                )
        if not spec.cls.raw_input:
            missing = set(spec.input_types) - set(spec.inputs) - spec.cls.optional_inputs
            for port in sorted(missing):
                errors.append(
                    f"{where}.inputs.{port}: required input is not connected ({spec.input_types[port].__name__})"
                )
    if errors:
        raise GraphError("\n".join(errors))
    return graph


def load(path: str | Path, **overrides: Any) -> Graph:
    """Load, override (see :func:`apply_overrides`) and check a graph file."""
    doc = load_document(path)
    return check(apply_overrides(doc, source=str(path), **overrides), source=str(path))
