"""The control protocol between the launcher and its node processes.

Every node process has a DEALER socket (identity = node name) connected to the
launcher's ROUTER; a second DEALER (identity ``name#hb``) is owned by the node's
heartbeat thread. Each control message is one MessagePack map with a ``kind``:

node -> launcher
    hello      {endpoint}                        bound its publisher; wants peers
    ready      {}                                set up, every subscriber connected
    heartbeat  {busy_secs, stats}                every ``HEARTBEAT_SECS``
    counts     {published, received}             lockstep: after each handled batch
    wait_idle  {}                                lockstep: reply when the graph is idle
    stop_request {reason, exit_code}             a node asks the graph to stop (exit_code:
                                                 its verdict on the run, 0 = success)
    final      {stats}                           on a clean exit
launcher -> node
    connect    {endpoints: {node: endpoint}}     where each input's publisher is
    start      {}                                every node is ready: go
    idle       {}                                answer to wait_idle
    stop       {}                                stop cleanly now
"""

from __future__ import annotations

from typing import Any

import msgpack

HEARTBEAT_SECS = 0.5


def pack(kind: str, **body: Any) -> bytes:
    """One control message."""
    packed: bytes = msgpack.packb({"kind": kind, **body}, use_bin_type=True)
    return packed


def unpack(raw: bytes) -> dict[str, Any]:
    """Decode one control message (peers are our own processes; still, check the shape)."""
    msg = msgpack.unpackb(raw, raw=False)
    if not isinstance(msg, dict) or not isinstance(msg.get("kind"), str):
        raise ValueError("control message without a 'kind'")
    return msg
