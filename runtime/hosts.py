"""A graph on several hosts: the ``hosts:`` table, node placement and endpoints.

::

    hosts:
      robot:       {address: 10.77.0.1, ports: [24000, 24099], public_key: "<Z85>"}
      workstation: {address: 10.77.0.2, ports: [24000, 24099], public_key: "<Z85>",
                    key_file: /etc/softbubble/workstation.key}   # optional
    on_host_lost: stop          # or wait (default stop)
    host_timeout_secs: 3.0      # a host silent this long is lost (default 3)
    max_clock_offset_secs: 0.005  # a launcher refuses to run above it (default 5 ms)
    nodes:
      world: {impl: world.sim, host: robot, ...}

A node's ``host:`` names a row of the table (a node without one runs on the first
host). Each host's launcher binds its link to the others on the first port of its range
and its nodes' publishers, in the order the graph lists them, on the ports after it, so
every host knows every endpoint from the graph alone. tcp on an address that is not
loopback is CURVE-encrypted (``runtime.security``): such a host needs ``public_key``.
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from runtime.security import is_public_key

HOST_KEYS = {"address", "ports", "public_key", "key_file"}
HOST_POLICIES = ("wait", "stop")
DEFAULTS: dict[str, Any] = {
    "on_host_lost": "stop",
    "host_timeout_secs": 3.0,
    "max_clock_offset_secs": 0.005,
}
TOP_KEYS = {"hosts", *DEFAULTS}


@dataclass(frozen=True)
class HostSpec:
    """One row of the hosts table."""

    name: str
    address: str
    first_port: int
    last_port: int
    public_key: str | None = None
    key_file: str | None = None

    @property
    def loopback(self) -> bool:
        return ipaddress.ip_address(self.address).is_loopback

    def endpoint(self, port: int) -> str:
        address = f"[{self.address}]" if ":" in self.address else self.address
        return f"tcp://{address}:{port}"

    @property
    def link(self) -> str:
        """Where this host's launcher listens to the others."""
        return self.endpoint(self.first_port)


@dataclass(frozen=True)
class Hosts:
    """The checked table and its policies; empty ``table`` for a one-host graph."""

    table: dict[str, HostSpec]
    on_host_lost: str = "stop"
    host_timeout_secs: float = 3.0
    max_clock_offset_secs: float = 0.005

    @property
    def encrypted(self) -> bool:
        """Whether any host is on an address that is not loopback (CURVE on its tcp)."""
        return any(not h.loopback for h in self.table.values())

    def placement(self, nodes: Mapping[str, str | None]) -> dict[str, str]:
        """node -> host, from each node's ``host`` (the first host for one without);
        empty without a table."""
        first = next(iter(self.table), None)
        return {node: host or first for node, host in nodes.items() if first}

    def endpoints(self, nodes: Mapping[str, str | None]) -> dict[str, str]:
        """node -> the endpoint its publisher binds (ports after each host's link port)."""
        placed = self.placement(nodes)
        used = {name: 0 for name in self.table}
        out = {}
        for node, host in placed.items():
            used[host] += 1
            spec = self.table[host]
            out[node] = spec.endpoint(spec.first_port + used[host])
        return out


def without_hosts(doc: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of graph document ``doc`` for one machine: no hosts table, none of its
    policies, no node's ``host:`` (a graph without a table is returned as it is)."""
    if "hosts" not in doc:
        return dict(doc)
    out = {k: v for k, v in doc.items() if k not in TOP_KEYS}
    nodes = doc.get("nodes")
    if isinstance(nodes, Mapping):
        out["nodes"] = {
            name: {k: v for k, v in body.items() if k != "host"}
            if isinstance(body, Mapping)
            else body
            for name, body in nodes.items()
        }
    return out


def _port_range(value: Any, where: str, errors: list[str]) -> tuple[int, int] | None:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(p, int) and not isinstance(p, bool) for p in value)
        and 1024 <= value[0] < value[1] <= 65535
    )
    if not ok:
        errors.append(
            f"{where}.ports: must be [first, last], 1024 <= first < last <= 65535, got {value!r}"
        )
        return None
    return value[0], value[1]


def check_mapping(body: Any, where: str, valid: set[str], needs: str, errors: list[str]) -> bool:
    """Whether ``body`` is a mapping (else an error saying it ``needs``); its keys not in
    ``valid`` are errors too."""
    if not isinstance(body, Mapping):
        errors.append(f"{where}: must be a mapping with {needs}, got {body!r}")
        return False
    for key in sorted(set(body) - valid, key=str):
        errors.append(f"{where}: unknown key {key!r} (valid: {sorted(valid)})")
    return True


def _row(name: Any, body: Any, where: str, errors: list[str]) -> HostSpec | None:
    if not check_mapping(body, where, HOST_KEYS, "address and ports", errors):
        return None
    address = body.get("address")
    try:
        loopback = ipaddress.ip_address(address).is_loopback
    except ValueError:
        errors.append(f"{where}.address: must be an IP address, got {address!r}")
        return None
    ports = _port_range(body.get("ports"), where, errors)
    key = body.get("public_key")
    if key is None and not loopback:
        errors.append(
            f"{where}.public_key: required: {address} is not a loopback address, so its "
            "tcp is encrypted with CURVE and the others must know its key (make one with "
            f"`python launch.py keys make {name}`)"
        )
    elif key is not None and not is_public_key(key):
        errors.append(f"{where}.public_key: must be a Z85 CURVE public key (40 characters)")
        key = None
    key_file = body.get("key_file")
    if key_file is not None and (not isinstance(key_file, str) or not key_file):
        errors.append(f"{where}.key_file: must be a path, got {key_file!r}")
        key_file = None
    if ports is None:
        return None
    return HostSpec(str(name), str(address), ports[0], ports[1], key, key_file)


def check_hosts(doc: Mapping[str, Any], source: str, errors: list[str]) -> Hosts:
    """The ``hosts:`` table and policies of ``doc`` (errors appended, naming the field)."""
    table: dict[str, HostSpec] = {}
    raw = doc.get("hosts")
    if raw is None:
        for key in sorted(set(DEFAULTS) & set(doc)):
            errors.append(f"{source}: {key}: only with a 'hosts' table")
        return Hosts({})
    if not isinstance(raw, Mapping) or not raw:
        errors.append(f"{source}: hosts: must be a non-empty mapping of host names, got {raw!r}")
        return Hosts({})
    for name, body in raw.items():
        row = _row(name, body, f"{source}: hosts.{name}", errors)
        if row is not None:
            table[row.name] = row
    values = {key: doc.get(key, default) for key, default in DEFAULTS.items()}
    if values["on_host_lost"] not in HOST_POLICIES:
        errors.append(
            f"{source}: on_host_lost: must be one of {HOST_POLICIES}, got {values['on_host_lost']!r}"
        )
    for key in ("host_timeout_secs", "max_clock_offset_secs"):
        value = values[key]
        if (
            not isinstance(value, int | float)
            or isinstance(value, bool)
            or not 0 < value < math.inf
        ):
            errors.append(f"{source}: {key}: must be a finite number > 0, got {value!r}")
            values[key] = DEFAULTS[key]
    rows = list(table.values())
    for i, a in enumerate(rows):
        for b in rows[i + 1 :]:
            if (
                a.address == b.address
                and a.first_port <= b.last_port
                and b.first_port <= a.last_port
            ):
                errors.append(
                    f"{source}: hosts.{b.name}.ports: overlaps {a.name}'s on the same address"
                )
    return Hosts(
        table,
        str(values["on_host_lost"]),
        float(values["host_timeout_secs"]),
        float(values["max_clock_offset_secs"]),
    )


def check_placement(
    hosts: Hosts, nodes: Mapping[str, str | None], source: str, errors: list[str]
) -> None:
    """Each node's host is a row of the table, and each host's range has room for its nodes."""
    for node, host in nodes.items():
        if host is not None and host not in hosts.table:
            errors.append(
                f"{source}: node {node!r}.host: {host!r} is not a host of the hosts table "
                f"({', '.join(hosts.table)})"
            )
    known = {n: h for n, h in nodes.items() if h is None or h in hosts.table}
    if not hosts.table:
        return
    counts: dict[str, int] = {}
    for host in hosts.placement(known).values():
        counts[host] = counts.get(host, 0) + 1
    for host, count in counts.items():
        spec = hosts.table[host]
        if spec.last_port - spec.first_port < count:
            errors.append(
                f"{source}: hosts.{host}.ports: {count} node(s) and the link need {count + 1} "
                f"ports, [{spec.first_port}, {spec.last_port}] has "
                f"{spec.last_port - spec.first_port + 1}"
            )
