"""Graphs: the checked model (nodes, producers, consumers, reachability) and its checker.

A graph file (YAML, read with a duplicate-key-refusing ``safe_load``, see
:mod:`runtime.graphfile`)::

    nodes:
      contact_patch: {impl: contact_patch, inputs: {left: left_camera/image, ...}}
      pose:
        impl: pose_estimator.ipopt            # registered name, or module:Class
        params: {object: mug, max_points: 4000}
        inputs: {patch: {from: contact_patch/patch, policy: latest}}
        restart: {policy: on-failure, max_restarts: 3, backoff_secs: 0.5}
        required: true                        # a final crash stops the graph
        host: 127.0.0.1                       # tcp on this address; ipc otherwise
                                              # (a host's name with a hosts: table,
                                              # see runtime.hosts)

:func:`check` runs the node checks (name, keys, implementation, parameters, inputs'
form, restart policy, host, socket path) on each node, then the edge checks (each
input has one producer of the right type, each required input is connected, each topic
one publisher) on the nodes that passed: a node that failed its own checks has unknown
ports, so edges into or out of it are not reported again. Every error names the file,
the node and the field; they are raised together as one :class:`GraphError`.

Checking imports only the module of each implementation a graph names (its class is
where its ports and parameters are declared); it starts no process.
"""

from __future__ import annotations

import ipaddress
import math
import re
import tempfile
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import msgspec
import zmq
from msgspec import Meta

from messages.base import Message
from messages.errors import GraphError
from runtime.graphfile import apply_overrides, load_document, parse_yaml
from runtime.hosts import TOP_KEYS as HOSTS_TOP_KEYS
from runtime.hosts import Hosts, check_hosts, check_mapping, check_placement
from runtime.node import Node
from runtime.params import MAX_SECS, ParamError, build_params
from runtime.registry import resolve

__all__ = ["Graph", "InputSpec", "NodeSpec", "RestartSpec", "check", "load"]
__all__ += ["apply_overrides", "load_document", "parse_yaml"]  # the file side, for callers

POLICIES = ("queue", "latest")
RestartPolicy = Literal["never", "on-failure"]
RESTART_POLICIES: tuple[str, ...] = get_args(RestartPolicy)
NODE_KEYS = {"impl", "params", "inputs", "restart", "required", "host", "hang_timeout_secs"}
TOP_KEYS = {"nodes", "name", "description", *HOSTS_TOP_KEYS}
MAX_QUEUE_SIZE = 2**31 - 1  # ZeroMQ's high-water mark is a C int
MAX_RESTARTS = 1000
NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_\-]*")
# The launcher's run directory: tempfile.mkdtemp(prefix=f"{RUNDIR_PREFIX}{pid}-").
RUNDIR_PREFIX = "sbg-"


def ipc_path(rundir: str | Path, name: str) -> str:
    """Where node ``name`` binds its publisher when it has no ``host``."""
    return f"{rundir}/{name}.pub"


def _longest_ipc_path(name: str) -> str:
    # the largest Linux pid has 7 digits; mkdtemp adds 8 characters
    rundir = Path(tempfile.gettempdir()) / (RUNDIR_PREFIX + "9" * 7 + "-" + "x" * 8)
    return ipc_path(rundir, name)


@dataclass(frozen=True)
class InputSpec:
    """One edge into a node: the topic it reads and how it queues."""

    port: str
    topic: str
    policy: str = "queue"
    queue_size: int = 1000


class RestartSpec(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What the supervisor does when a node dies or stops answering."""

    policy: Annotated[RestartPolicy, Meta(description="restart a node that fails, or not")] = (
        "never"
    )
    max_restarts: Annotated[int, Meta(ge=0, le=MAX_RESTARTS)] = 5
    backoff_secs: Annotated[float, Meta(ge=0, description="wait before the first restart")] = 0.5
    backoff_max_secs: Annotated[
        float, Meta(ge=0, description="the wait doubles up to this (>= backoff_secs)")
    ] = 8.0

    def __post_init__(self) -> None:
        if not self.backoff_max_secs >= self.backoff_secs:
            raise ValueError(
                f"`backoff_max_secs` must be >= backoff_secs ({self.backoff_secs}), "
                f"got {self.backoff_max_secs!r}"
            )


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


def _reach(start: Iterable[str], edges: Mapping[str, set[str]]) -> set[str]:
    """Every node reachable from ``start`` along ``edges``, ``start`` included."""
    seen = set(start)
    todo = list(seen)
    while todo:
        for nxt in edges.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


@dataclass
class Graph:
    """A checked graph, ready to launch: its nodes and, computed once, its wiring.

    Attributes:
        producers: topic -> the node publishing it (the first, if the checker found two).
        types: topic -> the message type published on it.
        consumers: topic -> ``(node, port)`` of every input reading it.
        feeds: node -> the nodes reading any of its topics (its direct consumers).
        fed_by: node -> the nodes whose topics it reads (its direct producers).
    """

    source: str
    nodes: dict[str, NodeSpec]
    document: dict[str, Any]
    hosts: Hosts = field(default_factory=lambda: Hosts({}))
    producers: dict[str, str] = field(init=False)
    types: dict[str, type[Message]] = field(init=False)
    consumers: dict[str, list[tuple[str, str]]] = field(init=False)
    feeds: dict[str, set[str]] = field(init=False)
    fed_by: dict[str, set[str]] = field(init=False)

    def __post_init__(self) -> None:
        self.producers, self.types = {}, {}
        for spec in self.nodes.values():
            for out, kind in spec.outputs.items():
                topic = spec.topic(out)
                if topic not in self.producers:
                    self.producers[topic] = spec.name
                    self.types[topic] = kind
        self.consumers = defaultdict(list)
        self.feeds = {name: set() for name in self.nodes}
        self.fed_by = {name: set() for name in self.nodes}
        for spec in self.nodes.values():
            for inp in spec.inputs.values():
                self.consumers[inp.topic].append((spec.name, inp.port))
                producer = self.producers.get(inp.topic)
                if producer is not None:
                    self.feeds[producer].add(spec.name)
                    self.fed_by[spec.name].add(producer)
        self.consumers = dict(self.consumers)

    def providers(self) -> dict[str, tuple[str, type[Message]]]:
        """Topic -> (publishing node, message type)."""
        return {topic: (node, self.types[topic]) for topic, node in self.producers.items()}

    def edges(self) -> list[tuple[str, str, str]]:
        """(topic, subscribing node, port) for every input of every node."""
        return [
            (inp.topic, spec.name, inp.port)
            for spec in self.nodes.values()
            for inp in spec.inputs.values()
        ]

    def downstream(self, start: Iterable[str], *, skip: Iterable[str] = ()) -> set[str]:
        """Nodes reachable from ``start`` along edges (``start`` included), not through ``skip``."""
        avoid = set(skip)
        return _reach(start, {n: c - avoid for n, c in self.feeds.items() if n not in avoid})

    def upstream(self, start: Iterable[str], *, skip: Iterable[str] = ()) -> set[str]:
        """Nodes from which ``start`` can be reached (``start`` included), not through ``skip``."""
        avoid = set(skip)
        return _reach(start, {n: p - avoid for n, p in self.fed_by.items() if n not in avoid})

    def fan_ins(self) -> set[str]:
        """Nodes that read the topics of two or more publishers, ``merges_in_any_order``
        ones (the recorder) left out: in lockstep they hold what they receive until the
        graph has settled, then handle it in a fixed order (``runtime.runner``)."""
        return {
            name
            for name, spec in self.nodes.items()
            if not spec.cls.merges_in_any_order and len(self.fed_by[name]) > 1
        }

    def release_order(self) -> list[str]:
        """The fan-ins and the stamp-ordered nodes, upstream first: the order lockstep lets
        them handle what they hold.

        One at a time, and the first in this order that holds something: a fan-in
        released together with one upstream of it would handle what it holds before the
        upstream one's outputs arrived, or after, as timing has it. Upstream first, it
        holds those outputs too, and handles them all in its fixed order. A cycle (a
        supervisor commanding the gripper it reads) is entered at its first node in the
        graph's order.
        """
        left = list(self.nodes)
        order: list[str] = []
        while left:
            ready = [n for n in left if not self.fed_by[n] & set(left) - {n}]
            take = ready[0] if ready else left[0]
            order.append(take)
            left.remove(take)
        holders = self.fan_ins() | self.stamp_ordered()
        return [n for n in order if n in holders]

    def stamp_ordered(self) -> set[str]:
        """Nodes with two or more of their ``ordered_inputs`` wired: they hand those
        inputs' messages over in stamp order (``runtime.ordering``)."""
        return {
            name
            for name, spec in self.nodes.items()
            if len(set(spec.cls.ordered_inputs) & set(spec.inputs)) > 1
        }

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
        fan_ins = self.fan_ins()
        return {
            topic
            for topic in self.producers
            if self.downstream(node for node, _ in self.consumers.get(topic, ())) & fan_ins
        }


# -- node checks ---------------------------------------------------------------------------------


def _restart(value: Any, where: str, errors: list[str]) -> RestartSpec:
    if value is None:
        return RestartSpec()
    if isinstance(value, str):
        value = {"policy": value}
    if not isinstance(value, dict):
        errors.append(f"{where}.restart: must be a policy name or a mapping, got {value!r}")
        return RestartSpec()
    try:
        spec: RestartSpec = build_params(RestartSpec, value)
    except ParamError as err:
        errors.append(f"{where}.{err.line('restart')}")
        return RestartSpec()
    return spec


def _input(port: str, ref: Any, where: str, errors: list[str]) -> InputSpec | None:
    if isinstance(ref, str):
        ref = {"from": ref}
    if not isinstance(ref, dict) or not isinstance(ref.get("from"), str):
        errors.append(
            f"{where}.inputs.{port}: must be 'node/output' or {{from: node/output, ...}}, got {ref!r}"
        )
        return None
    unknown = set(ref) - {"from", "policy", "queue_size"}
    if unknown:
        errors.append(
            f"{where}.inputs.{port}: unknown key(s) {sorted(unknown)}; "
            "valid: from, policy, queue_size"
        )
    topic = ref["from"]
    if topic.count("/") != 1 or not all(topic.split("/")):
        errors.append(f"{where}.inputs.{port}: must be of the form node/output, got {topic!r}")
        return None
    policy = ref.get("policy", "queue")
    if policy not in POLICIES:
        errors.append(f"{where}.inputs.{port}.policy: must be one of {POLICIES}, got {policy!r}")
    size = ref.get("queue_size", 1000)
    if not isinstance(size, int) or isinstance(size, bool) or not 1 <= size <= MAX_QUEUE_SIZE:
        errors.append(
            f"{where}.inputs.{port}.queue_size: must be an integer in [1, {MAX_QUEUE_SIZE}], "
            f"got {size!r}"
        )
        size = 1000
    return InputSpec(port=port, topic=topic, policy=policy, queue_size=size)


def _host(host: Any, where: str, errors: list[str], table: Hosts) -> str | None:
    """A host of the graph's table, or (without one) an address of this machine the node's
    publisher can bind (tried now, as the node will at start) that is loopback: tcp
    elsewhere is encrypted, with the keys only a hosts table names."""
    if host is None or table.table:
        return host if isinstance(host, str) else None
    if not isinstance(host, str) or not host.strip() or host != host.strip() or "/" in host:
        errors.append(
            f"{where}.host: must be an address or interface of this machine, got {host!r}"
        )
        return None
    ctx: zmq.Context[Any] = zmq.Context.instance()
    sock = ctx.socket(zmq.PUB)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        sock.bind(f"tcp://{host}:*")
        bound = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
    except zmq.ZMQError as err:
        errors.append(
            f"{where}.host: must be an address or interface of this machine, got {host!r} "
            f"(binding tcp://{host}:* fails: {err.strerror})"
        )
        return None
    finally:
        sock.close(linger=0)
    address = ipaddress.ip_address(bound.removeprefix("tcp://").rpartition(":")[0].strip("[]"))
    if not address.is_loopback:
        errors.append(
            f"{where}.host: must be a loopback address (127.0.0.1), got {host!r} (it binds "
            f"{address}): tcp there would carry frames unencrypted and unauthenticated; "
            "put the node on a host of a `hosts:` table with that host's CURVE public key "
            "(docs/hosts.md)"
        )
        return None
    return host


def _check_name(name: Any, where: str, errors: list[str]) -> bool:
    if not isinstance(name, str) or not NODE_NAME.fullmatch(name):
        errors.append(
            f"{where}: a node name must be a letter or '_' then letters, digits, '_' or '-'"
        )
        return False
    return True


def _check_node(
    name: str, body: Any, source: str, errors: list[str], hosts: Hosts
) -> NodeSpec | None:
    """One node's own checks; its spec, or None when its ports cannot be known."""
    where = f"{source}: node {name!r}"
    if not check_mapping(body, where, NODE_KEYS, "'impl'", errors):
        return None
    impl = body.get("impl")
    if not isinstance(impl, str):
        errors.append(f"{where}.impl: required, a registered name or module:Class")
        return None
    try:
        cls = resolve(impl)
    except KeyError as err:
        errors.append(f"{where}.impl: {err.args[0]}")
        return None
    raw_params = body.get("params") or {}
    if not isinstance(raw_params, Mapping):
        errors.append(f"{where}.params: must be a mapping, got {raw_params!r}")
        return None
    try:
        params = build_params(cls.Params, raw_params)
        inputs_decl, outputs = cls.ports(params)
    except ParamError as err:
        errors.append(f"{where}.{err.line()}")
        return None
    except (ValueError, TypeError) as err:  # ports() of a node reading a file (replay)
        errors.append(f"{where}.params: {err}")
        return None
    inputs: dict[str, InputSpec] = {}
    refs = body.get("inputs") or {}
    if not isinstance(refs, Mapping):
        errors.append(f"{where}.inputs: must be a mapping port -> node/output, got {refs!r}")
        refs = {}
    for port, ref in refs.items():
        if not cls.raw_input and port not in inputs_decl:
            errors.append(
                f"{where}.inputs.{port}: {impl} has no input {port!r} (inputs: {sorted(inputs_decl)})"
            )
            continue
        parsed = _input(str(port), ref, where, errors)
        if parsed is not None:
            inputs[str(port)] = parsed
    hang = body.get("hang_timeout_secs", 30.0)
    if not isinstance(hang, int | float) or isinstance(hang, bool) or not 0 < hang < math.inf:
        errors.append(f"{where}.hang_timeout_secs: must be a finite number > 0, got {hang!r}")
        hang = 30.0
    elif hang > MAX_SECS:
        errors.append(f"{where}.hang_timeout_secs: must be at most {MAX_SECS:g} s, got {hang!r}")
        hang = 30.0
    required = body.get("required", True)
    if not isinstance(required, bool):
        errors.append(f"{where}.required: must be true or false, got {required!r}")
    host = _host(body.get("host"), where, errors, hosts)
    if host is None and "host" not in body and not hosts.table:
        path = _longest_ipc_path(name)
        if len(path.encode()) > zmq.IPC_PATH_MAX_LEN:
            errors.append(
                f"{where}: the name is too long for its socket path ({path!r} would be "
                f"{len(path.encode())} bytes, the OS allows {zmq.IPC_PATH_MAX_LEN}): "
                "shorten the name, set TMPDIR to a shorter folder, or give the node a host"
            )
    return NodeSpec(
        name=name,
        impl=impl,
        cls=cls,
        params=params,
        raw_params=dict(raw_params),
        inputs=inputs,
        input_types=dict(inputs_decl),
        outputs=dict(outputs),
        restart=_restart(body.get("restart"), where, errors),
        required=bool(required),
        host=host,
        hang_timeout_secs=float(hang),
    )


# -- edge checks ---------------------------------------------------------------------------------


def _check_edges(graph: Graph, failed: set[str], errors: list[str]) -> None:
    """Edges between nodes that passed their own checks; ``failed`` nodes' edges are skipped."""
    source = graph.source
    for spec in graph.nodes.values():
        for out in spec.outputs:
            topic = spec.topic(out)
            first = graph.producers[topic]
            if first != spec.name:
                errors.append(
                    f"{source}: node {spec.name!r}.outputs: topic {topic!r} is also published "
                    f"by {first!r}"
                )
    for spec in graph.nodes.values():
        where = f"{source}: node {spec.name!r}"
        for port, inp in spec.inputs.items():
            node, _, out = inp.topic.partition("/")
            if inp.topic not in graph.producers:
                if node in failed:
                    continue  # that node's own error is the root cause
                if node in graph.nodes:
                    outs = sorted(graph.nodes[node].outputs)
                    errors.append(
                        f"{where}.inputs.{port}: node {node!r} has no output {out!r} (outputs: {outs})"
                    )
                else:
                    errors.append(f"{where}.inputs.{port}: no node publishes {inp.topic!r}")
                continue
            if spec.cls.raw_input:
                continue
            got, want = graph.types[inp.topic], spec.input_types[port]
            if got is not want:
                errors.append(
                    f"{where}.inputs.{port}: type mismatch: {inp.topic} carries {got.__name__}, "
                    f"{spec.impl} expects {want.__name__}"
                )
        if not spec.cls.raw_input:
            missing = set(spec.input_types) - set(spec.inputs) - spec.cls.optional_inputs
            for port in sorted(missing):
                errors.append(
                    f"{where}.inputs.{port}: required input is not connected "
                    f"({spec.input_types[port].__name__})"
                )


def check(doc: Mapping[str, Any], source: str = "<graph>") -> Graph:
    """Check a graph document completely; raise one GraphError listing every root cause."""
    if (
        not isinstance(doc, Mapping)
        or not isinstance(doc.get("nodes"), Mapping)
        or not doc["nodes"]
    ):
        raise GraphError(f"{source}: a graph needs a non-empty 'nodes' mapping")
    errors = [
        f"{source}: unknown top-level key {key!r} (valid: {sorted(TOP_KEYS)})"
        for key in sorted(set(doc) - TOP_KEYS, key=str)
    ]
    hosts = check_hosts(doc, source, errors)
    specs: dict[str, NodeSpec] = {}
    failed: set[str] = set()
    for name, body in doc["nodes"].items():
        spec = None
        if _check_name(name, f"{source}: node {name!r}", errors):
            spec = _check_node(name, body, source, errors, hosts)
        if spec is None:
            failed.add(str(name))
        else:
            specs[name] = spec
    if hosts.table:
        check_placement(hosts, {name: spec.host for name, spec in specs.items()}, source, errors)
    graph = Graph(source=source, nodes=specs, document=dict(doc), hosts=hosts)
    _check_edges(graph, failed, errors)
    if errors:
        raise GraphError("\n".join(errors))
    return graph


def load(path: str | Path, **overrides: Any) -> Graph:
    """Load, override (see :func:`apply_overrides`) and check a graph file."""
    doc = load_document(path)
    return check(apply_overrides(doc, source=str(path), **overrides), source=str(path))
