"""Stamp order across a node's inputs (runtime.ordering): the same decision whatever the
order its inputs' messages arrive in, through the node runner's input layer (in this
process, no child), live and in lockstep."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from messages import GraspState, Header, ShearEstimate
from messages.base import Message
from messages.codec import encode
from messages.force import SlipState
from runtime.ordering import StampOrder
from runtime.registry import class_path
from runtime.runner import Runner
from runtime.zmqio import Input

MS = 1_000_000
INPUTS = {"grasp": "grasp_monitor/grasp", "shear": "shear/shear", "slip": "slip/slip"}


def grasp(ms: int, event: str = "") -> GraspState:
    return GraspState(header=Header(stamp_nanos=ms * MS), stable=bool(event), event=event)  # type: ignore[arg-type]


def shear(ms: int, px: float) -> ShearEstimate:
    return ShearEstimate(
        header=Header(stamp_nanos=ms * MS),
        sensor="left",
        shear_px=np.array([0.0, px]),
        magnitude_px=px,
        direction=np.array([0.0, 1.0]),
        direction_defined=True,
        shear_m=np.array([0.0, px * 1e-4]),
    )


def slip(ms: int, onset: str = "") -> SlipState:
    return SlipState(header=Header(stamp_nanos=ms * MS), sensor="left", phase="edge", onset=onset)  # type: ignore[arg-type]


def runner(tmp_path: Path, *, lockstep: bool) -> Runner:
    from nodes.supervisor.handover import HandoverSupervisor

    spec = {
        "name": "supervisor",
        "class_path": class_path(HandoverSupervisor),
        "params": {"release_on": "shear", "confirm_frames": 1},
        "outputs": {"command": "supervisor/command", "event": "supervisor/event"},
        "inputs": [
            {"port": port, "topic": topic, "provider": topic.split("/")[0], "policy": "queue"}
            for port, topic in INPUTS.items()
        ],
        "bind": f"ipc://{tmp_path}/supervisor",
        "control": f"ipc://{tmp_path}/control",  # nobody listens: counts go nowhere
        "secret": "00" * 32,
        "lockstep": lockstep,
    }
    return Runner(spec)


@pytest.fixture
def events(tmp_path: Path) -> Iterator[Any]:
    made: list[Runner] = []

    def run(arrivals: list[tuple[str, Message]], *, lockstep: bool) -> list[str]:
        """The task's events for ``arrivals`` delivered one by one through the runner."""
        r = runner(tmp_path, lockstep=lockstep)
        made.append(r)
        said: list[str] = []
        publish = r.io.publish

        def record(output: str, msg: Message) -> None:
            if output == "event":
                said.append(msg.event)  # type: ignore[attr-defined]
            publish(output, msg)

        r.io.publish = record  # type: ignore[method-assign]
        r.node.setup()
        wired = {p: Input(p, t, "queue", type(r.node).inputs[p]) for p, t in INPUTS.items()}
        for port, msg in arrivals:
            r._deliver(wired[port], encode(INPUTS[port], msg))
        if lockstep:  # the replay's last message: what is still held goes
            r.flush = True
            r._release()
        return said

    yield run
    for r in made:
        r.io.pub.close(linger=0)
        r.io.control.close(linger=0)
        r.ctx.term()


# A slip onset (camera -> wrench -> slip: the longer path) stamped before the shear that
# confirms a pull (camera -> shear), arriving after it, then every input moves on.
START = [("grasp", grasp(0)), ("grasp", grasp(400, "stable"))]
THEN = [("grasp", grasp(600)), ("shear", shear(600, 0.1)), ("slip", slip(600))]
SLIP_FIRST = [*START, ("slip", slip(480, "edge")), ("shear", shear(500, 2.0)), *THEN]
SHEAR_FIRST = [*START, ("shear", shear(500, 2.0)), ("slip", slip(480, "edge")), *THEN]


@pytest.mark.parametrize("lockstep", [False, True], ids=["live", "lockstep"])
def test_the_handover_decides_alike_whichever_path_delivers_first(
    events: Any, lockstep: bool
) -> None:
    # The squeeze answers the earlier frame, the release the later one: in stamp order
    # the task squeezes, then lets go, however the two arrived (handled as they arrived,
    # the shear first made it let go and then ignore the slip).
    expected = ["grasping", "stable", "squeeze", "release"]
    assert events(SLIP_FIRST, lockstep=lockstep) == expected
    assert events(SHEAR_FIRST, lockstep=lockstep) == expected


def test_a_message_waits_until_every_other_ordered_input_has_moved_past_it() -> None:
    order = StampOrder(["a", "b", "c"], window_nanos=None)
    order.add("b", grasp(10))
    assert order.ready() == []  # a and c have said nothing yet
    order.add("a", grasp(10))
    order.add("c", grasp(9))
    assert [port for port, _ in order.ready()] == ["c"]  # the others are past 9
    order.add("c", grasp(10))
    # Stamp 10 on every input: a goes (b and c are at 10 and come after it in the order);
    # b waits for a to pass 10 (a later a stamped 10 would sort before it), c for b.
    assert [port for port, _ in order.ready()] == ["a"]
    order.add("a", grasp(11))
    assert [port for port, _ in order.ready()] == ["b"]
    assert order.pending() == {"c": 1, "a": 1}
    assert [port for port, _ in order.flush()] == ["c", "a"]
    assert order.pending() == {}


def test_live_a_silent_input_holds_a_message_no_longer_than_the_window() -> None:
    order = StampOrder(["a", "b"], window_nanos=50 * MS)
    order.add("a", grasp(5), now_nanos=1000 * MS)
    order.add("a", grasp(3), now_nanos=1010 * MS)  # back in time: sorted before the first
    assert order.due_nanos() == 1050 * MS
    assert order.ready(now_nanos=1049 * MS) == []
    late = order.ready(now_nanos=1050 * MS)
    assert [m.header.stamp_nanos for _, m in late] == [3 * MS, 5 * MS]
    assert order.due_nanos() is None


def test_live_an_input_waits_only_for_the_inputs_it_names() -> None:
    order = StampOrder(["a", "b", "c"], window_nanos=500 * MS, waits={"c": ("a",)})
    order.add("b", grasp(5))
    order.add("c", grasp(10))
    order.add("a", grasp(12))
    # c waits for a alone: it goes past b's 5 (b waits for c, which is at 10: b goes too),
    # while b's next message, stamped 11, waits for c to pass 11.
    order.add("b", grasp(11))
    assert [(p, m.header.stamp_nanos // MS) for p, m in order.ready()] == [("b", 5), ("c", 10)]
    assert order.pending() == {"a": 1, "b": 1}
    # In lockstep the waits are ignored: c waits for b as well.
    exact = StampOrder(["a", "b", "c"], window_nanos=None, waits={"c": ("a",)})
    exact.add("c", grasp(10))
    exact.add("a", grasp(12))
    assert exact.ready() == []
    exact.add("b", grasp(11))
    assert [p for p, _ in exact.ready()] == ["c"]


def test_live_a_release_is_not_held_back_by_the_slip_path(events: Any) -> None:
    # The shear that confirms the pull has come, and the grasp monitor has moved past it;
    # the slip node, the longest path, has not: the shear rule reads nothing it brings.
    arrivals = [*START, ("grasp", grasp(600)), ("shear", shear(500, 2.0))]
    assert events(arrivals, lockstep=False) == ["grasping", "stable", "release"]
    # In lockstep the order stays exact: the release waits for the slip to pass it.
    assert events(arrivals, lockstep=True)[-1] == "release"
    assert events(arrivals[:-1] + [("slip", slip(480, "edge")), arrivals[-1]], lockstep=True) == [
        "grasping",
        "stable",
        "squeeze",
        "release",
    ]


def test_order_waits_must_name_ordered_inputs() -> None:
    from nodes.supervisor.handover import HandoverSupervisor

    class Careless(HandoverSupervisor):
        order_waits = {"shear": ("pose",)}  # pose goes straight through: nothing to wait for

    with pytest.raises(TypeError, match="order_waits names ports that are not ordered"):
        Careless.check_declaration()
    HandoverSupervisor.check_declaration()
