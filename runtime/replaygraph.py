"""The graph that replays a bag: the recorded graph with some nodes swapped and live, and a
``replay`` node publishing the recorded topics they need (see docs/bags.md).

``launch.py replay`` (``cli.replay``) runs the graph stored in the bag (or ``--graph``)
with the nodes named in ``--swap`` (and everything downstream of them) live (see
:func:`build_replay_graph`). A graph with a hosts table replays across its hosts, one
launcher per host (``--host NAME``, the replay node on the first host), or on this
machine alone with ``--no-hosts`` (docs/hosts.md).
"""

from __future__ import annotations

import copy
import logging
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from messages.errors import GraphError
from runtime.bag import BagReader, topic_filter

log = logging.getLogger(__name__)


class ReplayOptions(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How the replay node plays the bag (see :mod:`nodes.replay`)."""

    rate: Annotated[
        float,
        Meta(description="pace by the recorded receive times, scaled (2.0 = twice as fast)", gt=0),
    ] = 1.0
    fast: Annotated[
        bool,
        Meta(description="as fast as the graph takes them (at most window messages in flight)"),
    ] = False
    loop: Annotated[bool, Meta(description="start over at the end")] = False
    start_secs: Annotated[
        float, Meta(description="cut the bag: seconds from its first message", ge=0)
    ] = 0.0
    end_secs: Annotated[
        float | None,
        Meta(description="cut the bag: seconds from its first message (None: to its end)"),
    ] = None
    topics: Annotated[str, Meta(description="select topics: a regular expression (re.search)")] = ""
    remap: Annotated[
        dict[str, str], Meta(description="rename topics: {bag_topic: published_topic}")
    ] = msgspec.field(default_factory=dict)
    lockstep: Annotated[
        bool,
        Meta(
            description="the same bag through the same nodes gives the same outputs whatever the load"
        ),
    ] = False
    strict: Annotated[
        bool,
        Meta(description="stop at the first message that does not decode (else skip and count it)"),
    ] = False

    def __post_init__(self) -> None:
        if self.end_secs is not None and self.end_secs <= self.start_secs:
            raise ValueError(
                f"end_secs must be > start_secs ({self.start_secs}), got {self.end_secs}"
            )
        for src, dst in self.remap.items():
            if "/" not in dst:
                raise ValueError(f"remap: {src!r} -> {dst!r}: a topic is 'node/output'")


def exact_topics(topics: Sequence[str]) -> str:
    """A ``topics`` pattern that selects exactly these topics."""
    return "^(?:" + "|".join(re.escape(t) for t in sorted(topics)) + ")$"


def _keep_known_params(name: str, body: dict[str, Any]) -> None:
    """Drop the parameters a swapped-in implementation does not take (they were the old one's)."""
    from runtime.params import field_names
    from runtime.registry import resolve

    try:
        cls = resolve(body["impl"])
    except KeyError:
        return  # the checker reports the unknown implementation
    known = set(field_names(cls.Params))
    params = body.get("params") or {}
    dropped = sorted(set(params) - known)
    if dropped:
        log.warning(
            "replay: %s is now %s; dropping its old parameters %s", name, body["impl"], dropped
        )
        body["params"] = {k: v for k, v in params.items() if k in known}


def build_replay_graph(
    graph: Mapping[str, Any],
    bag_path: Path,
    swap: Mapping[str, str],
    options: ReplayOptions | None = None,
) -> dict[str, Any]:
    """The graph that replays ``bag_path`` through ``graph`` with some nodes swapped.

    The nodes named in ``swap`` get their new implementation (an empty string keeps
    theirs; parameters the new one does not take are dropped, with a warning) and run
    live, as does every node downstream of them, except one that also feeds back into
    their inputs (a loop through a simulated world): the replay stays open-loop there, with
    a warning. Every topic the live nodes read comes from a ``replay`` node if the bag has
    it; otherwise the node publishing it runs live too (and so on upstream). All other
    nodes, recorders included, are left out. The walk is the checked graph's
    (:meth:`runtime.graph.Graph.downstream` and ``upstream``).
    With nothing swapped, the replay node publishes every selected topic.

    Raises:
        GraphError: an unknown node in ``swap``, or a needed topic that is neither in
            the bag nor published by a node that can run.
        BagError: the bag cannot be read.
    """
    from runtime.graph import check  # the checker resolves node classes and their ports

    options = options or ReplayOptions()
    doc = copy.deepcopy(dict(graph))
    nodes: dict[str, Any] = doc.get("nodes") or {}
    for name, impl in swap.items():
        if name not in nodes:
            raise GraphError(
                f"{bag_path}: --swap {name}: the graph has no node {name!r} "
                f"(nodes: {', '.join(nodes)})"
            )
        if impl and impl != nodes[name].get("impl"):
            nodes[name]["impl"] = impl
            _keep_known_params(name, nodes[name])
    checked = check(doc, source=f"{bag_path} (replay graph)")
    recorders = {n for n, spec in checked.nodes.items() if spec.cls.raw_input}
    providers = checked.producers
    inputs = {n: [i.topic for i in spec.inputs.values()] for n, spec in checked.nodes.items()}
    swapped = set(swap)
    downstream = checked.downstream(swapped, skip=recorders) - swapped
    upstream = checked.upstream(swapped, skip=recorders) - swapped
    # A node both downstream and upstream of a swapped one closes a loop back into its
    # inputs (a supervisor commanding the simulated world that the cameras see): running
    # it live would make the world live too, so the replay stays open-loop there and that
    # node's topics come from the bag. Name it in --swap to run it live anyway.
    live = swapped | (downstream - upstream)
    direct = set().union(*(checked.feeds[n] for n in swapped)) - swapped
    for name in sorted(downstream & upstream & direct):
        log.warning(
            "replay: %s is downstream of %s but feeds back into its inputs; "
            "it does not rerun, its recorded topics stand (add --swap %s to run it live)",
            name,
            ", ".join(sorted(swapped)),
            name,
        )

    with BagReader(bag_path) as reader:
        bag_topics = list(reader.topics())
    chosen = topic_filter(options.topics)
    available = {options.remap.get(t, t): t for t in bag_topics if chosen(t)}

    while True:  # pull in live producers for topics the bag lacks, until nothing changes
        needed = {t: n for n in sorted(live) for t in inputs[n]}
        missing = [
            (t, n) for t, n in needed.items() if providers.get(t) not in live and t not in available
        ]
        if not missing:
            break
        for topic, reader_node in missing:
            maker = providers.get(topic)
            if maker is None or maker in recorders:
                raise GraphError(
                    f"{bag_path}: topic {topic!r} (read by {reader_node!r}) is neither in the "
                    f"bag nor published by a node of the graph"
                )
            live.add(maker)
    replayed = {t: available[t] for n in live for t in inputs[n] if providers.get(t) not in live}
    if not live:
        replayed = dict(available)
    if not replayed:
        raise GraphError(f"{bag_path}: nothing to replay: the live nodes read no recorded topic")

    if options.lockstep:
        for name in sorted(n for n in live if checked.nodes[n].cls.clocked):
            log.warning(
                "replay: %s (%s) follows the clock or a device, not the bag: lockstep cannot "
                "make its outputs, or what follows from them, the same twice",
                name,
                nodes[name].get("impl"),
            )
    out_nodes = {n: nodes[n] for n in nodes if n in live}
    name = "replay"
    while name in out_nodes:
        name += "_"
    bag_names = sorted(set(replayed.values()))
    params: dict[str, Any] = {
        "path": str(bag_path),
        "rate": options.rate,
        "fast": options.fast,
        "loop": options.loop,
        "start_secs": options.start_secs,
        "topics": exact_topics(bag_names),
        "remap": {bag: pub for pub, bag in replayed.items() if pub != bag},
        "lockstep": options.lockstep,
        "strict": options.strict,
    }
    if options.end_secs is not None:
        params["end_secs"] = options.end_secs
    out_nodes[name] = {"impl": "replay", "params": params, "required": True}
    result = {k: v for k, v in doc.items() if k != "nodes"}
    result["nodes"] = out_nodes
    return result
