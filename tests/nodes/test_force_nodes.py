"""The ``wrench`` and ``slip`` nodes and the handover's force rules, through FakeIO."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import sim
from messages.base import Header
from messages.force import BubbleContact, SlipState, WrenchEstimate
from messages.types import GraspState, GripperState, Pressure, ShearEstimate
from nodes.slip import SlipNode
from nodes.supervisor.handover import HandoverParams, HandoverSupervisor
from nodes.wrench import WrenchNode
from runtime.params import ParamError
from runtime.testing import feed, make_node


@pytest.fixture(scope="module")
def fill_frames() -> list[sim.Instant]:
    """A light grasp of a mug being filled: 2.7 s (it slips from about 2 s)."""
    scene = sim.load_scene("scenes/mug_fill.yaml")
    scene = dataclasses.replace(scene, duration_secs=2.7)
    simulator = sim.Simulator(scene)
    frames = []
    while not simulator.world.done:
        frames.append(simulator.step())
    return frames


def drive_wrench(frames: list[sim.Instant]) -> tuple[WrenchNode, object]:
    node, io = make_node(WrenchNode, {})
    for inst in frames:
        feed(node, "gripper", inst.gripper)
        for side in ("left", "right"):
            feed(node, f"{side}_pressure", inst.pressures[side])
        for side in ("left", "right"):
            feed(node, side, inst.images[side])
    return node, io


def test_wrench_node_estimates_the_grip_and_the_weight(fill_frames: list[sim.Instant]) -> None:
    _, io = drive_wrench(fill_frames)
    estimates = io.published["wrench"]
    contacts = io.published["contact"]
    assert len(contacts) == 2 * len(fill_frames)
    assert len(estimates) == len(fill_frames)  # one per pair of frames of an instant
    by_stamp = {e.header.stamp_nanos: e for e in estimates}
    # At 1.5 s: 6 N of grip, about 0.35 + 0.25 kg of mug and water carried.
    inst = next(i for i in fill_frames if i.snapshot.time_secs >= 1.5)
    est, truth = by_stamp[inst.stamp_nanos], inst.wrench
    assert truth is not None and est.method == "physics"
    assert est.in_contact == [True, True]
    # Within three of its own sigmas (the calibration's residual spread) of the truth.
    sigma = est.bubble_force_sigma_n
    assert np.all(sigma > 0) and np.all(est.object_force_sigma_n > 0)
    assert np.all(np.abs(est.bubble_force_n - truth.bubble_force_n) <= 3 * sigma)
    assert abs(est.object_force_n[1] - truth.object_force_n[1]) <= 3 * est.object_force_sigma_n[1]
    assert est.object_force_n[1] > 0.5 * truth.object_force_n[1] > 0  # holds the mug up
    # Before the jaws close: no contact, no force.
    first = estimates[0]
    assert first.in_contact == [False, False] and not np.any(first.bubble_force_n)


def test_slip_node_reports_an_onset_once_the_patch_slips(fill_frames: list[sim.Instant]) -> None:
    _, wio = drive_wrench(fill_frames)
    node, io = make_node(SlipNode, {})
    stable_at = next(i for i in fill_frames if i.snapshot.time_secs >= 0.9).stamp_nanos
    feed(
        node, "grasp", GraspState(header=Header(stamp_nanos=stable_at), stable=True, event="stable")
    )
    for msg in wio.published["contact"]:
        if msg.header.stamp_nanos >= stable_at:
            feed(node, "contact", msg)
    states: list[SlipState] = io.published["slip"]
    onsets = [(s.header.stamp_nanos, s.sensor, s.onset) for s in states if s.onset]
    assert onsets, "the filled mug slips"
    true_edge = next(
        i.stamp_nanos
        for i in fill_frames
        if i.snapshot.wrench and i.snapshot.wrench["left"].slipping_fraction > 0
    )
    # Not late: by two frames after the truth's first slipping point. It may warn a
    # little early (it fires at 0.9 of the calibration's median limit).
    assert onsets[0][0] <= true_edge + 2 * int(1e9 / 30)
    # No onset while the mug was not yet being filled (a constant load, well inside).
    filling = next(i.stamp_nanos for i in fill_frames if i.snapshot.time_secs >= 1.0)
    before = [s for s in states if s.header.stamp_nanos < filling]
    assert before and not any(s.onset for s in before)


def test_wrench_node_refuses_a_missing_calibration_naming_the_field() -> None:
    with pytest.raises(ParamError, match="calibration"):
        make_node(WrenchNode, {"calibration": "models/force/none.json"})


def _wrench(
    stamp: int, fz: float, fy: float = 3.4, in_contact: tuple[bool, bool] = (True, True)
) -> WrenchEstimate:
    z3 = np.zeros(3)
    return WrenchEstimate(
        header=Header(stamp_nanos=stamp),
        method="physics",
        bubble_force_n=np.zeros((2, 3)),
        bubble_torque_nm=np.zeros((2, 3)),
        bubble_force_sigma_n=np.zeros((2, 3)),
        bubble_torque_sigma_nm=np.zeros((2, 3)),
        object_force_n=np.array([0.0, fy, fz]),
        object_torque_nm=z3,
        object_force_sigma_n=z3,
        object_torque_sigma_nm=z3,
        in_contact=list(in_contact),
        area_m2=[0.002, 0.002],
    )


def _holding_handover() -> tuple[HandoverSupervisor, object]:
    node, io = make_node(HandoverSupervisor, {"grasp_width_m": 0.07, "start_delay_secs": 0.0})
    feed(node, "wrench", _wrench(10, 0.0))
    feed(node, "grasp", GraspState(header=Header(stamp_nanos=20), stable=True, event="stable"))
    assert node.state == "holding"
    feed(node, "wrench", _wrench(25, 0.0))  # the baseline: after the stable grasp
    return node, io


def test_handover_releases_on_a_pull_in_the_force() -> None:
    node, io = _holding_handover()
    feed(node, "wrench", _wrench(30, -0.7))
    assert node.state == "holding"
    feed(node, "wrench", _wrench(40, -0.9))
    assert node.state == "releasing"
    assert io.published["command"][-1].command == "release"


def test_handover_takes_no_baseline_from_before_the_stable_grasp() -> None:
    # On a loaded machine the wrench stream lags the grasp monitor's: when the grasp
    # turns stable, the newest estimate (and some still in flight) are from the
    # closing. Taken as the baseline, a steady hold after it read as a pull.
    node, io = make_node(HandoverSupervisor, {"grasp_width_m": 0.07, "start_delay_secs": 0.0})
    feed(node, "wrench", _wrench(10, -1.0))
    feed(node, "grasp", GraspState(header=Header(stamp_nanos=20), stable=True, event="stable"))
    feed(node, "wrench", _wrench(15, -1.0))  # in flight from before the stable grasp
    for k in range(5):
        feed(node, "wrench", _wrench(30 + k, 0.0))
    assert node.state == "holding"
    assert "release" not in [e.event for e in io.published["event"]]


def test_handover_counts_only_estimates_with_both_bubbles_in_contact() -> None:
    # A bubble that missed its free reference (or whose frame was dropped) sees no
    # contact: an estimate of half the grasp is no pull.
    node, io = _holding_handover()
    for k in range(5):
        feed(node, "wrench", _wrench(30 + k, -2.0, in_contact=(True, False)))
    assert node.state == "holding"
    feed(node, "wrench", _wrench(40, -0.9))
    feed(node, "wrench", _wrench(41, -0.9))
    assert node.state == "releasing"


def test_handover_uses_the_shear_rule_until_the_force_has_a_baseline() -> None:
    node, _ = make_node(HandoverSupervisor, {"grasp_width_m": 0.07, "start_delay_secs": 0.0})
    feed(node, "grasp", GraspState(header=Header(stamp_nanos=20), stable=True, event="stable"))
    feed(node, "wrench", _wrench(25, 0.0, in_contact=(False, True)))  # one bubble: no baseline
    for k in range(3):
        feed(node, "shear", _shear(30 + k, 2.0))
    assert node.state == "releasing"


def test_handover_lets_the_shear_rule_stand_in_while_the_force_lags() -> None:
    # The wrench node behind (a loaded machine): its newest estimate is 0.3 s older than
    # the shear's, more than `force_max_lag_secs`; the shear rule answers the pull.
    node, _ = _holding_handover()  # the force's baseline at 25 ns
    lagging = int(0.3e9)
    for k in range(3):
        feed(node, "shear", _shear(lagging + k, 2.0))
    assert node.state == "releasing"
    # A current force rule decides alone: the same shear does nothing.
    node, _ = _holding_handover()
    for k in range(3):
        feed(node, "shear", _shear(30 + k, 2.0))
    assert node.state == "holding"


def _shear(stamp: int, magnitude_px: float) -> ShearEstimate:
    direction = np.array([0.0, 1.0])
    return ShearEstimate(
        header=Header(stamp_nanos=stamp),
        sensor="left",
        shear_px=direction * magnitude_px,
        magnitude_px=magnitude_px,
        direction=direction,
        direction_defined=True,
        shear_m=direction * magnitude_px * 0.2e-3,
    )


def test_handover_squeezes_on_slip_when_the_load_grows_under_gravity() -> None:
    node, io = _holding_handover()
    feed(node, "wrench", _wrench(30, 0.0, fy=9.0))  # heavier: not a pull
    feed(
        node,
        "slip",
        SlipState(header=Header(stamp_nanos=40), sensor="left", phase="edge", onset="edge"),
    )
    command = io.published["command"][-1]
    assert node.state == "holding" and command.command == "grasp"
    assert 12.0 < command.force_n <= 40.0
    events = [e.event for e in io.published["event"]]
    assert "squeeze" in events and "release" not in events
    assert isinstance(io.published["event"][-1].detail, str)
    _ = (BubbleContact, GripperState, Pressure)


def test_handover_with_the_shear_rule_ignores_the_force() -> None:
    node, io = make_node(
        HandoverSupervisor,
        {"grasp_width_m": 0.07, "start_delay_secs": 0.0, "release_on": "shear"},
    )
    feed(node, "wrench", _wrench(10, 0.0))
    feed(node, "grasp", GraspState(header=Header(stamp_nanos=20), stable=True, event="stable"))
    for k in range(5):
        feed(node, "wrench", _wrench(30 + k, -3.0))
    assert node.state == "holding"
    with pytest.raises(ParamError, match="release_on"):
        make_node(HandoverSupervisor, {"release_on": "vibes"})


def test_wrench_node_estimates_only_instants_both_bubbles_saw_when_one_was_dropped(
    fill_frames: list[sim.Instant],
) -> None:
    node, io = make_node(WrenchNode, {})
    for k, inst in enumerate(fill_frames[:10]):
        feed(node, "gripper", inst.gripper)
        for side in ("left", "right"):
            feed(node, f"{side}_pressure", inst.pressures[side])
        sides = ("left",) if 5 <= k <= 7 else ("left", "right")  # right's frames 5-7 dropped
        for side in sides:
            feed(node, side, inst.images[side])
    stamps = [e.header.stamp_nanos for e in io.published["wrench"]]
    # An estimate mixing two instants is wrong by the load's change between them: the
    # instants whose right frame was lost get none, and pairing resumes with frame 8.
    assert stamps == [fill_frames[k].stamp_nanos for k in (0, 1, 2, 3, 4, 8, 9)]
    assert len(io.published["contact"]) == 17  # every frame measured


def test_wrench_node_estimates_do_not_depend_on_the_order_inputs_arrive_in(
    fill_frames: list[sim.Instant],
) -> None:
    # Live the inputs of one instant come from four processes in any order: here the
    # images one instant behind the pressures and the gripper, and the left camera a
    # further frame behind the right (a slower ray-cast). Each estimate must be the one
    # of its instant as if everything had come in order (a late partner is waited for,
    # the pressure taken at the frame's stamp), not a pair of two instants.
    frames = fill_frames[:40]
    _, in_order = drive_wrench(frames)
    node, io = make_node(WrenchNode, {})
    for k in range(len(frames) + 2):
        if k < len(frames):
            feed(node, "gripper", frames[k].gripper)
            for side in ("left", "right"):
                feed(node, f"{side}_pressure", frames[k].pressures[side])
        if 1 <= k <= len(frames):
            feed(node, "right", frames[k - 1].images["right"])
        if 2 <= k:
            feed(node, "left", frames[k - 2].images["left"])
    got = io.published["wrench"]
    want = in_order.published["wrench"]
    assert [e.header.stamp_nanos for e in got] == [e.header.stamp_nanos for e in want]
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a.bubble_force_n, b.bubble_force_n, rtol=1e-9, atol=1e-12)


def test_handover_stamps_the_release_with_the_estimate_that_decided() -> None:
    # Live the grasp and the shear need not wait for the wrench path (Node.order_waits):
    # the grasp monitor's newest message can be stamped after the estimates that confirm
    # the pull. The release is the data time of its deciding estimate, not that newest.
    node, io = _holding_handover()
    feed(node, "grasp", GraspState(header=Header(stamp_nanos=60), stable=True))
    feed(node, "wrench", _wrench(30, -0.7))
    feed(node, "wrench", _wrench(40, -0.9))
    (release,) = [e for e in io.published["event"] if e.event == "release"]
    assert release.header.stamp_nanos == 40


def test_handover_answers_no_slip_onset_from_before_the_stable_grasp() -> None:
    # The grasp no longer waits for the slip path: an onset from the closing can come
    # after the stable grasp. It is no slip of the held object.
    node, io = _holding_handover()  # stable at 20
    onset = SlipState(header=Header(stamp_nanos=15), sensor="left", phase="edge", onset="edge")
    feed(node, "slip", onset)
    assert [e.event for e in io.published["event"]][-1] == "stable"
    assert io.published["command"][-1].command == "grasp"
    assert io.published["command"][-1].force_n == HandoverParams().grasp_force_n
