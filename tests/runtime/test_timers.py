"""Cancelling a node's timers: in the node runner (in this process, no child) and in FakeIO."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.node import Node
from runtime.registry import class_path
from runtime.runner import Runner
from runtime.testing import make_node


class TwoTimers(Node):
    """``first`` cancels ``second`` and, on its second call, itself."""

    def setup(self) -> None:
        self.calls: list[str] = []
        self.io.add_timer(0.01, self.first)
        self.io.add_timer(0.01, self.second)

    def first(self) -> None:
        self.calls.append("first")
        self.io.cancel_timer(self.second)
        if self.calls.count("first") == 2:
            self.io.cancel_timer(self.first)

    def second(self) -> None:
        self.calls.append("second")


@pytest.fixture
def runner(tmp_path: Path) -> Iterator[Runner]:
    spec = {
        "name": "timers",
        "class_path": class_path(TwoTimers),
        "params": {},
        "outputs": {},
        "inputs": [],
        "bind": f"ipc://{tmp_path}/timers",
        "control": f"ipc://{tmp_path}/control",  # nobody listens: nothing is sent here
        "secret": "00" * 32,
    }
    runner = Runner(spec)
    yield runner
    runner.io.pub.close(linger=0)
    runner.io.control.close(linger=0)
    runner.ctx.term()


def _all_due(runner: Runner) -> None:
    for timer in runner.io.timers:
        timer.due_nanos = 0


def test_a_timer_cancelled_by_another_in_the_same_round_does_not_run(runner: Runner) -> None:
    node = runner.node
    assert isinstance(node, TwoTimers)
    node.setup()
    _all_due(runner)
    runner._run_timers()
    assert node.calls == ["first"]
    assert [t.callback for t in runner.io.timers] == [node.first]
    _all_due(runner)
    runner._run_timers()  # first cancels itself: no timer is left to wake the loop
    assert node.calls == ["first", "first"]
    assert runner.io.timers == []
    runner._run_timers()
    assert node.calls == ["first", "first"]


def test_fake_io_cancels_timers_as_the_runner_does() -> None:
    node, io = make_node(TwoTimers)
    io.advance(1.0)
    assert node.calls == ["first", "first"]  # second was cancelled before its first call
    io.cancel_timer(node.second)  # no timer with it any more: nothing happens
