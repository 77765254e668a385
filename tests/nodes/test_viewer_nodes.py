"""The viewer nodes with a fake IO: every frame shown, a bad one counted, not fatal."""

from __future__ import annotations

import socket
from pathlib import Path

from rerun.chunk import RrdReader

from messages.base import Header
from messages.codec import encode
from messages.types import GraspState, Pressure
from nodes.viewer import FoxgloveViewer, RerunViewer
from runtime.testing import make_node


def _pressure(seq: int) -> Pressure:
    return Pressure(
        header=Header(stamp_nanos=seq * 10**7, seq=seq), sensor="left", pressure_pa=100.0 * seq
    )


def test_rerun_viewer_saves_every_frame_and_skips_a_bad_one(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "live.rrd"
    node, _ = make_node(RerunViewer, {"target": str(out)}, name="viewer")
    for seq in range(5):
        node.on_raw("left_pressure/pressure", encode("left_pressure/pressure", _pressure(seq)))
    node.on_raw("left_pressure/pressure", [b"left_pressure/pressure", b"not msgpack \xc1"])
    grasp = GraspState(header=Header(stamp_nanos=3), stable=True, event="stable")
    node.on_raw("grasp_monitor/grasp", encode("grasp_monitor/grasp", grasp))
    node.teardown()
    assert node.bad_frames == {"left_pressure/pressure": 1}
    rows: dict[str, int] = {}
    for chunk in RrdReader(out).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/pressure/left"] == 5
    assert rows["/events/grasp"] == 1


def test_foxglove_viewer_serves_on_its_port() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    node, _ = make_node(FoxgloveViewer, {"port": port}, name="viewer")
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # the WebSocket server accepts connections
        node.on_raw("left_pressure/pressure", encode("left_pressure/pressure", _pressure(1)))
        assert node.sink.written == 1
        assert node.server.port == port
    finally:
        node.teardown()
