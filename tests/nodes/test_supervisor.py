"""The task supervisors as state machines, driven through FakeIO."""

from __future__ import annotations

import numpy as np
import pytest

from messages import ClassProbabilities, GraspState, Header, ShearEstimate
from messages.tasks import GraspSummary
from nodes.supervisor.handover import HandoverSupervisor
from nodes.supervisor.sort import SortSupervisor
from runtime.params import build_params
from runtime.testing import feed, make_node


def shear(sensor: str, magnitude_px: float, *, defined: bool = True) -> ShearEstimate:
    direction = np.array([0.0, 1.0]) if defined else np.zeros(2)
    return ShearEstimate(
        header=Header(),
        sensor=sensor,
        shear_px=direction * magnitude_px,
        magnitude_px=magnitude_px,
        direction=direction,
        direction_defined=defined,
        shear_m=direction * magnitude_px * 0.2e-3,
    )


def grasp(t_secs: float, event: str = "") -> GraspState:
    """A grasp monitor message at data time ``t_secs``."""
    stamp = int(1e18 + t_secs * 1e9)
    return GraspState(header=Header(stamp_nanos=stamp), stable=event == "stable", event=event)


def events(io) -> list[str]:
    return [e.event for e in io.published["event"]]


def test_handover_grasps_waits_for_stable_and_releases_on_a_sustained_pull() -> None:
    node, io = make_node(HandoverSupervisor, {"confirm_frames": 3, "release_shear_px": 1.0})
    io.advance(5.0)  # the wall clock does not drive the task: its data does
    feed(node, "grasp", grasp(0.0))
    assert not io.published["command"]
    feed(node, "grasp", grasp(0.4))  # start_delay_secs (0.3) after the first message
    assert [c.command for c in io.published["command"]] == ["grasp"]
    assert io.published["command"][0].header.stamp_nanos == grasp(0.4).header.stamp_nanos
    feed(node, "shear", shear("left", 5.0))  # not holding yet: ignored
    feed(node, "grasp", grasp(0.5, "stable"))
    for magnitude in (2.0, 2.0, 0.1, 2.0, 2.0):  # interrupted: no release yet
        feed(node, "shear", shear("left", magnitude))
    assert "release" not in events(io)
    feed(node, "shear", shear("left", 0.0, defined=False))
    feed(node, "shear", shear("right", 2.0))
    feed(node, "shear", shear("right", 2.0))
    feed(node, "shear", shear("right", 2.0))
    assert events(io)[-1] == "release"
    assert io.published["command"][-1].command == "release"
    assert (
        "right bubble" in io.published["event"][-1].detail
        and "90 deg" in io.published["event"][-1].detail
    )
    feed(node, "grasp", grasp(0.9, "released"))
    assert events(io)[-2:] == ["done", "summary"]
    assert io.stop_reason.startswith("handover: done: held 0.")
    summary = io.published["event"][-1].data
    assert isinstance(summary, GraspSummary) and summary.sorted is None
    assert summary.release.startswith("pull on the right bubble")


def test_handover_times_out_without_a_grasp() -> None:
    node, io = make_node(HandoverSupervisor, {"timeout_secs": 2.0})
    for t_secs in (0.0, 1.0, 2.5):
        feed(node, "grasp", grasp(t_secs))
    assert events(io) == ["grasping", "timeout"] and io.stop_reason == "handover: timeout"


def test_a_task_that_hears_nothing_times_out_on_the_wall_clock() -> None:
    node, io = make_node(HandoverSupervisor, {"timeout_secs": 2.0})
    io.advance(1.0)
    assert not events(io)
    io.advance(2.0)
    assert events(io) == ["timeout"] and "no input" in io.published["event"][0].detail


def test_sort_votes_then_routes_to_the_bin() -> None:
    node, io = make_node(SortSupervisor, {"vote_frames": 3})
    feed(node, "grasp", grasp(0.0))
    feed(node, "grasp", grasp(0.5, "stable"))
    classes = ["mug", "pet_bottle", "square_bottle", "wine_glass"]
    for p in ([0.1, 0.7, 0.1, 0.1], [0.1, 0.6, 0.2, 0.1], [0.5, 0.3, 0.1, 0.1]):
        feed(
            node,
            "classes",
            ClassProbabilities(header=Header(), classes=classes, probabilities=np.float32(p)),
        )
    detail = next(e.detail for e in io.published["event"] if e.event == "classified")
    assert detail.startswith("pet_bottle") and detail.endswith("recycling")
    assert io.published["command"][-1].command == "release"
    feed(node, "grasp", grasp(0.9, "released"))
    assert events(io)[-2:] == ["done", "summary"]
    summary = io.published["event"][-1].data
    assert isinstance(summary, GraspSummary) and summary.sorted is not None
    assert summary.sorted.class_name == "pet_bottle" and summary.sorted.bin == "recycling"
    assert summary.held_secs == 0.0  # the outputs carry no stamp: the clock stood still
    assert io.stop_reason.startswith("sort: done: held 0.00 s, released: pet_bottle (")
    assert io.stop_reason.endswith("placed in recycling")


def test_sort_sends_an_unsure_object_to_the_unsure_bin() -> None:
    node, io = make_node(SortSupervisor, {"vote_frames": 2, "min_confidence": 0.9})
    feed(node, "grasp", grasp(0.0))
    feed(node, "grasp", grasp(0.5, "stable"))
    classes = ["mug", "pet_bottle", "square_bottle", "wine_glass"]
    for p in ([0.05, 0.95, 0.0, 0.0], [0.1, 0.8, 0.1, 0.0]):  # mean 0.875 for pet_bottle
        feed(
            node,
            "classes",
            ClassProbabilities(header=Header(), classes=classes, probabilities=np.float32(p)),
        )
    assert "classified" not in events(io)
    detail = next(e.detail for e in io.published["event"] if e.event == "unsure")
    assert detail.startswith("pet_bottle (0.875 < 0.9)") and detail.endswith("manual")
    assert io.published["command"][-1].command == "release"


def test_params_check_themselves() -> None:
    with pytest.raises(ValueError, match="release_shear_px"):
        build_params(HandoverSupervisor.Params, {"release_shear_px": 0})
    with pytest.raises(ValueError, match="vote_frames"):
        build_params(SortSupervisor.Params, {"vote_frames": 0})
    with pytest.raises(ValueError, match="min_confidence"):
        build_params(SortSupervisor.Params, {"min_confidence": 1.5})


def stamped_shear(t_secs: float, magnitude_px: float) -> ShearEstimate:
    msg = shear("left", magnitude_px)
    msg.header = Header(stamp_nanos=grasp(t_secs).header.stamp_nanos)
    return msg


@pytest.mark.parametrize("early", [False, True], ids=["in_stamp_order", "newer_first"])
def test_the_time_held_is_the_data_of_the_grasp_and_the_pull_whatever_came_first(
    early: bool,
) -> None:
    # Live, a message stamped later (a shear frame) can reach the task before the grasp
    # monitor's stable grasp; a lockstep replay hands them over in stamp order. The time
    # held is from the stable grasp's stamp to the stamp of the frame that decided the
    # release, either way (it once took the newest stamp seen at each: 2.6 s live
    # against 2.7 s in the replay of the same run).
    node, io = make_node(HandoverSupervisor, {"confirm_frames": 2, "release_shear_px": 1.0})
    feed(node, "grasp", grasp(0.0))
    feed(node, "grasp", grasp(0.4))
    if early:
        feed(node, "shear", stamped_shear(0.9, 0.1))
    feed(node, "grasp", grasp(0.5, "stable"))
    if not early:
        feed(node, "shear", stamped_shear(0.9, 0.1))
    feed(node, "shear", stamped_shear(2.0, 2.0))
    feed(node, "shear", stamped_shear(2.1, 2.0))
    assert events(io)[-1] == "release"
    feed(node, "grasp", grasp(2.6, "released"))
    summary = io.published["event"][-1].data
    assert isinstance(summary, GraspSummary)
    assert summary.held_secs == pytest.approx(1.6)  # 0.5 s to 2.1 s
