"""Check a graph document and run it: on this machine, or this host's part of it.

A graph with a ``hosts:`` table runs as one launcher per host (``--host NAME``, see
``runtime.hosts`` and docs/hosts.md). Without ``--host`` such a graph is not started:
the command prints the command to run on each host. Every host is started with the same
options: with ``--record`` each launcher adds the same recorder node (its parameters hold
the command line without ``--host``/``--keys``), which runs on the first host of the
table while the others' publishers wait for its subscriptions; with ``--lockstep`` the
launchers pass their nodes' counts to each other so the idle barrier covers every edge.
The launchers' link compares a digest of the graph and the run mode, so a host started
with other options is refused, naming the flags that differ.
"""

from __future__ import annotations

import argparse
import shlex
import socket
import sys
from pathlib import Path
from typing import Any

from cli.taps import add_recorder, add_viewer, viewer_refused
from messages.errors import GraphError
from runtime import graph as graphs
from runtime.graph import Graph, check
from runtime.launcher import Launcher
from runtime.security import KeyPair, default_key_dir, load_key


def host_keys(graph: Graph, host: str, key_dir: Path | None) -> KeyPair | None:
    """This host's CURVE key pair, if any host of the graph is off loopback; else None.

    Raises:
        GraphError: ``host`` is not in the table, or its key file is missing, readable by
            others, malformed, or not the key pair whose public key the graph names.
    """
    table = graph.hosts.table
    if host not in table:
        raise GraphError(
            f"{graph.source}: --host {host!r} is not a host of the graph's hosts table "
            f"({', '.join(table)})"
        )
    if not graph.hosts.encrypted:
        return None
    spec = table[host]
    path = Path(spec.key_file) if spec.key_file else (key_dir or default_key_dir()) / f"{host}.key"
    if not path.exists():
        raise GraphError(
            f"{graph.source}: host {host!r} needs its secret key at {path} (make it there with "
            f"`python launch.py keys make {host}`, or give --keys DIR or the host's key_file)"
        )
    keys = load_key(path)
    if spec.public_key is not None and keys.public != spec.public_key:
        raise GraphError(
            f"{graph.source}: hosts.{host}.public_key is not the public key of {path} "
            f"({keys.public})"
        )
    return keys


def check_here(graph: Graph, host: str) -> None:
    """Whether this machine can be ``host``: its link port binds here, now.

    Raises:
        GraphError: the address is not this machine's, or the port is taken (a launcher
            for that host runs already, or another program holds it).
    """
    spec = graph.hosts.table[host]
    family = socket.AF_INET6 if ":" in spec.address else socket.AF_INET
    # A plain socket, closed at once (a ZeroMQ socket's close is asynchronous, and the
    # launcher binds the port right after), with ZeroMQ's SO_REUSEADDR.
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((spec.address, spec.first_port))
            sock.listen()
        except OSError as err:
            raise GraphError(
                f"{graph.source}: --host {host}: cannot listen on {spec.link} here "
                f"({err.strerror}): is this machine {host} ({spec.address}), and is no "
                f"launcher for {host} running?"
            ) from err


def host_commands(graph: Graph, argv: list[str]) -> str:
    """What to run on each host of ``graph`` (``argv``: this command line, without --host)."""
    placed = graph.hosts.placement({n: s.host for n, s in graph.nodes.items()})
    lines = [
        f"{graph.source} places its nodes on {len(graph.hosts.table)} hosts: run one launcher "
        "on each (the order does not matter):"
    ]
    for name, spec in graph.hosts.table.items():
        nodes = [n for n, h in placed.items() if h == name]
        lines.append(f"  on {name} ({spec.address}, nodes {', '.join(nodes) or '-'}):")
        lines.append(f"    {shlex.join([*argv, '--host', name])}")
    return "\n".join(lines)


def launch(
    graph: dict[str, Any],
    *,
    source: str,
    record: Path | None = None,
    topics: str | None = None,
    overwrite: bool = False,
    lockstep: bool = False,
    duration_secs: float | None = None,
    log_level: str = "INFO",
    command_line: str = "",
    host: str | None = None,
    key_dir: Path | None = None,
) -> int:
    """Check and run a graph document; returns the exit code (2 when the check fails)."""
    try:
        if record is not None:
            graph = add_recorder(
                graph,
                record,
                topics,
                command_line or " ".join(sys.argv),
                source,
                overwrite=overwrite,
            )
        checked = check(graph, source=source)
        if checked.hosts.table and host is None:
            print(host_commands(checked, [sys.executable, *sys.argv]), file=sys.stderr)
            return 2
        if host is not None and not checked.hosts.table:
            raise GraphError(f"{source}: --host {host!r}: the graph has no hosts table")
        keys = host_keys(checked, host, key_dir) if host is not None else None
        if host is not None:
            check_here(checked, host)
        launcher = Launcher(
            checked,
            lockstep=lockstep,
            duration_secs=duration_secs,
            log_level=log_level,
            host=host,
            keys=keys,
            argv=command_line,
        )
    except GraphError as err:
        print(f"graph check failed:\n{err}", file=sys.stderr)
        return 2
    return launcher.run()


def emulated(doc: dict[str, Any], rig_file: str | None) -> dict[str, Any]:
    """The graph on an emulated rig (``sim.rig_launch``); its errors as graph errors."""
    from sim.rig_launch import activate, emulate

    try:
        rig, feed, _ = activate(rig_file)
        return emulate(doc, rig=rig, feed=feed)
    except ValueError as err:
        raise GraphError(str(err)) from err


def main(args: argparse.Namespace) -> int:
    """``launch.py [run] GRAPH ...``: check the graph, then run it or say it is OK."""
    refused = None if args.check else viewer_refused(args.view)
    if refused:
        print(refused, file=sys.stderr)
        return 2
    import nodes  # noqa: F401 - the index of node implementations (no node module)

    source = str(args.graph)
    try:
        doc = graphs.load_document(args.graph)
        if args.emulate:
            doc = emulated(doc, args.rig)
        elif args.rig:
            raise GraphError(f"{source}: --rig needs --emulate")
        only = [n for n in args.only.split(",") if n]
        doc = graphs.apply_overrides(
            doc, sets=args.sets, swaps=args.swaps, only=only, source=source
        )
        if args.view is not None:
            doc = add_viewer(doc, args.view, source=source)
        checked = check(doc, source=source)
    except GraphError as err:
        print(f"graph check failed:\n{err}", file=sys.stderr)
        return 2
    if args.check:
        if args.host is not None:
            try:
                keys = host_keys(checked, args.host, args.keys)
                check_here(checked, args.host)
            except GraphError as err:
                print(f"graph check failed:\n{err}", file=sys.stderr)
                return 2
            on = f"; host {args.host}" + (", its key matches" if keys else "")
        elif checked.hosts.table:
            on = f"; hosts: {', '.join(checked.hosts.table)} (run each with --host NAME)"
        else:
            on = ""
        print(f"{source}: OK, {len(checked.nodes)} nodes, {len(checked.edges())} edges{on}")
        return 0
    return launch(
        doc,
        source=source,
        record=args.record,
        topics=args.record_topics,
        overwrite=args.overwrite,
        lockstep=args.lockstep,
        duration_secs=args.duration,
        log_level=args.log_level,
        command_line=args.command_line,
        host=args.host,
        key_dir=args.keys,
    )
