"""The node runner's per-message path (in this process, no child): each input's handler is
bound once, yet a node that overrides ``handle`` still sees every message through it, the
heartbeat's busy mark is set while a handler runs, and nothing is handled once a stop is
requested."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from messages import Header, Tick, encode
from runtime.registry import class_path
from runtime.runner import Runner
from runtime.zmqio import Input
from tests.runtime.nodes_for_tests import TickDispatcher, TickRecorder

TOPIC = "clock/tick"


@pytest.fixture
def make(tmp_path: Path) -> Iterator[Any]:
    made: list[Runner] = []

    def build(cls: type[TickRecorder]) -> tuple[Runner, Input]:
        spec = {
            "name": "recorder",
            "class_path": class_path(cls),
            "params": {},
            "outputs": {},
            "inputs": [{"port": "tick", "topic": TOPIC, "provider": "clock", "policy": "queue"}],
            "bind": f"ipc://{tmp_path}/recorder-{len(made)}",
            "control": f"ipc://{tmp_path}/control",  # nobody listens
            "secret": "00" * 32,
        }
        runner = Runner(spec)
        made.append(runner)
        runner.node.setup()
        node = runner.node
        assert isinstance(node, TickRecorder)
        node.runner_busy = lambda: runner.busy_since > 0
        return runner, Input("tick", TOPIC, "queue", Tick)

    yield build
    for runner in made:
        runner.io.pub.close(linger=0)
        runner.io.control.close(linger=0)
        runner.ctx.term()


def _tick(seq: int) -> list[Any]:
    return encode(TOPIC, Tick(header=Header(seq=seq), value=float(seq)))


@pytest.mark.parametrize("cls", [TickRecorder, TickDispatcher])
def test_every_message_reaches_the_handler_marked_busy_and_none_after_a_stop(
    make: Any, cls: type[TickRecorder]
) -> None:
    runner, inp = make(cls)
    for seq in range(3):
        runner._deliver(inp, _tick(seq))
    node = runner.node
    assert isinstance(node, TickRecorder)
    assert node.seen == [(0.0, True), (1.0, True), (2.0, True)]
    assert runner.busy_since == 0.0  # not busy between messages
    if isinstance(node, TickDispatcher):
        assert node.dispatched == ["tick"] * 3  # through its own handle, every one
    runner.io.stop_requested = True
    runner._deliver(inp, _tick(3))
    assert len(node.seen) == 3
    assert inp.counters.received == 4  # counted, not handled
