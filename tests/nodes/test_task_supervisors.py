"""supervisor.antagonism and supervisor.stacking as state machines, through FakeIO."""

from __future__ import annotations

import numpy as np

from messages import GraspState, GroundTruth, Header, PoseEstimate, ShearEstimate
from messages.sim import PlacementTruth
from messages.tasks import PlacementSummary, TrackingSummary
from nodes.supervisor.antagonism import AntagonismSupervisor
from nodes.supervisor.stacking import StackingSupervisor
from runtime.testing import feed, make_node
from sim.scene import rotation_from_rpy_deg

T0 = int(1e18)


def stamp(t_secs: float) -> Header:
    return Header(stamp_nanos=T0 + int(round(t_secs * 1e9)))


def grasp(t_secs: float, event: str = "", stable: bool = False) -> GraspState:
    return GraspState(header=stamp(t_secs), stable=stable or event == "stable", event=event)


def pose_at(t_secs: float) -> np.ndarray:
    """The truth: still, a 20 degree roll from 1 to 2 s, and a tap at 3 s."""
    pose = np.eye(4)
    roll = 20.0 * float(np.clip(t_secs - 1.0, 0.0, 1.0))
    if t_secs >= 3.0:
        roll += 8.0
        pose[:3, 3] = [0.0, 0.003, 0.0]
    pose[:3, :3] = rotation_from_rpy_deg((roll, 0.0, 0.0))
    return pose


def truth(t_secs: float) -> GroundTruth:
    return GroundTruth(
        header=stamp(t_secs),
        tool_from_object=pose_at(t_secs),
        object_class="mug",
        in_contact=True,
        shear_left_m=np.zeros(2),
        shear_right_m=np.zeros(2),
        noise_seed=0,
    )


def estimate(t_secs: float, pose: np.ndarray) -> PoseEstimate:
    return PoseEstimate(
        header=stamp(t_secs),
        tool_from_object=pose,
        residual_rms_m=0.001,
        cost=0.0,
        iterations=3,
        status="ok",
        solve_secs=0.01,
        points_used=100,
    )


def run_antagonism(lag_frames: int, pose_first: bool = False) -> tuple[dict, object]:
    """Estimates that follow the truth ``lag_frames`` late after the tap (then exact);
    ``pose_first``: each estimate comes before the truth of its frame."""
    node, io = make_node(AntagonismSupervisor, {"track_secs": 4.0, "start_delay_secs": 0.0})
    feed(node, "grasp", grasp(-0.5))
    feed(node, "grasp", grasp(0.0, "stable"))
    for k in range(1, 30 * 5):
        t = k / 30
        behind = 3.0 <= t < 3.0 + lag_frames / 30
        messages = [
            ("truth", truth(t)),
            ("pose", estimate(t, pose_at(2.99) if behind else pose_at(t))),
        ]
        feed(node, "grasp", grasp(t, stable=True))
        for port, msg in messages[::-1] if pose_first else messages:
            feed(node, port, msg)
        if io.stop_reason:
            break
    (summary,) = [e.data for e in io.published["event"] if e.event == "summary"]
    assert isinstance(summary, TrackingSummary)
    return summary, io


def test_antagonism_reports_errors_and_the_time_to_reacquire_a_jolt() -> None:
    summary, io = run_antagonism(lag_frames=6)
    assert summary.axis_deg.median < 1e-6 and summary.axis_deg.max > 7.9
    (jolt,) = summary.jolts
    assert jolt.turned_deg > 7.9 and jolt.moved_mm > 2.9
    assert jolt.reacquire_secs is not None
    assert abs(jolt.reacquire_secs - 0.2) < 1e-6  # six frames behind
    assert summary.success and io.stop_exit_code == 0
    assert io.published["command"][-1].command == "release"


def test_antagonism_judges_the_same_whichever_of_estimate_and_truth_comes_first() -> None:
    truth_first, _ = run_antagonism(lag_frames=6)
    pose_first, _ = run_antagonism(lag_frames=6, pose_first=True)
    assert pose_first == truth_first and pose_first.unmatched == 0
    assert pose_first.estimates == 4 * 30


def test_antagonism_fails_when_an_estimate_never_comes_back() -> None:
    summary, io = run_antagonism(lag_frames=1000)
    assert summary.jolts[0].reacquire_secs is None
    assert not summary.success and io.stop_exit_code == 1


def shear(sensor: str, magnitude_px: float) -> ShearEstimate:
    return ShearEstimate(
        header=Header(),
        sensor=sensor,
        shear_px=np.array([magnitude_px, 0.0]),
        magnitude_px=magnitude_px,
        direction=np.array([1.0, 0.0]),
        direction_defined=magnitude_px > 0,
        shear_m=np.array([magnitude_px * 0.0002, 0.0]),
    )


def placement(event: str, gap_mm: float) -> PlacementTruth:
    return PlacementTruth(
        header=stamp(2.0),
        placed=event == "placed",
        t_secs=2.0,
        touch_secs=1.9,
        gap_m=gap_mm / 1000,
        push_m=0.001,
        tilt_deg=0.0,
    )


def test_stacking_releases_on_a_sustained_touch_and_reports_the_truth() -> None:
    for outcome, code in (("placed", 0), ("dropped", 1)):
        node, io = make_node(StackingSupervisor, {"confirm_frames": 2, "touch_shear_px": 1.0})
        feed(node, "grasp", grasp(0.0))
        feed(node, "grasp", grasp(0.4))
        feed(node, "grasp", grasp(0.8, "stable"))
        feed(node, "shear", shear("left", 2.0))
        feed(node, "shear", shear("left", 0.2))  # not sustained
        assert io.published["command"][-1].command == "grasp"
        feed(node, "shear", shear("right", 1.5))
        feed(node, "shear", shear("right", 1.5))
        assert io.published["command"][-1].command == "release"
        feed(node, "placement", placement(outcome, 0.0 if outcome == "placed" else 4.0))
        assert io.stop_reason is None  # still held until the grasp monitor says released
        feed(node, "grasp", grasp(1.2, "released"))
        (summary,) = [e.data for e in io.published["event"] if e.event == "summary"]
        assert isinstance(summary, PlacementSummary)
        assert summary.outcome == outcome and io.stop_exit_code == code
        assert summary.gap_mm == (0.0 if outcome == "placed" else 4.0)
        assert summary.push_mm == 1.0 and summary.touch_secs == 1.9
        assert io.stop_reason.startswith(f"stacking: {outcome}: gap")


def test_stacking_without_the_truth_ends_after_a_wait() -> None:
    node, io = make_node(StackingSupervisor, {"confirm_frames": 1, "placement_wait_secs": 0.5})
    feed(node, "grasp", grasp(0.0))
    feed(node, "grasp", grasp(0.4))
    feed(node, "grasp", grasp(0.8, "stable"))
    feed(node, "shear", shear("left", 3.0))
    feed(node, "grasp", grasp(1.0, "released"))
    assert io.stop_reason is None
    feed(node, "grasp", grasp(1.6))
    assert "unknown" in io.stop_reason and io.stop_exit_code == 0
