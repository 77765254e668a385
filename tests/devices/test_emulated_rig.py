"""``graphs/hardware.yaml`` itself, end to end, on the emulated rig (real processes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from geometry.se3 import invert
from messages.types import pose_is_known
from runtime.bag import BagReader
from tests.test_graphs import launch

pytestmark = pytest.mark.timeout(300)

PULL_SECS = 5.0  # scenes/rig_handover.yaml: the mug is held still until then


def topics(bag: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    for m in BagReader(bag).messages():
        out.setdefault(m.topic, []).append(m.decode())
    return out


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(axis degrees, offset mm) between two poses of the mug (its axis is object z)."""
    axis = np.degrees(np.arccos(np.clip(abs(estimate[:3, 2] @ truth[:3, 2]), -1.0, 1.0)))
    diff = invert(truth) @ estimate
    return float(axis), float(np.linalg.norm(diff[:3, 3]) * 1000.0)


def test_the_hardware_graph_hands_over_on_emulated_devices_and_replays(tmp_path: Path) -> None:
    bag = tmp_path / "rig.mcap"
    proc = launch("graphs/hardware.yaml", "--emulate", "--record", str(bag))
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:]
    # The drivers found the emulated devices, and said once that there is no calibration.
    assert "connected to WSG 50 at 127.0.0.1" in out
    assert out.count("no calibration file: the CAD camera mount") == 2
    assert "refused" not in out and "Traceback" not in out, out[-3000:]
    t = topics(bag)
    start = t["rig_world/state"][0].header.stamp_nanos
    events = [(e.event, (e.header.stamp_nanos - start) / 1e9) for e in t["supervisor/event"]]
    names = [name for name, _ in events]
    assert names == ["grasping", "stable", "release", "done", "summary"], events
    # The jaws open within a second of the pull's start, by the world's clock (the
    # supervisor's events are stamped by the sensors' clocks, which a loaded machine's
    # world lags behind).
    states = [(m.time_secs, m.width_m) for m in t["rig_world/state"]]
    opened = next(
        ts
        for (ts, w), (_, w0) in zip(states[1:], states[:-1], strict=True)
        if ts > 2.0 and w > w0 + 1e-4
    )
    assert PULL_SECS < opened < PULL_SECS + 1.0, opened

    # Every frame is placed in the tool frame; the contact patch and shear use them.
    for side in ("left", "right"):
        frames = t[f"{side}_camera/image"]
        assert len(frames) > 30 and all(pose_is_known(f.tool_from_sensor) for f in frames)
    patches = [p for p in t["contact_patch/patch"] if len(p.points_in_tool)]
    assert len(patches) > 10 and all(set(np.unique(p.bubble)) == {0, 1} for p in patches)
    assert any(s.has_reference and s.magnitude_px > 1.5 for s in t["shear/shear"])

    # Live, the pose node keeps the newest patch and solves at the speed the machine
    # allows (about 12 Hz on a quiet machine, a few Hz at a load average of 40 on two
    # cores): how many poses a live run makes is the machine's, so live the test asks for
    # poses `ok` while the mug is held, each where the mug is. Pose stamps are their
    # frames': the world's clock.
    truth = {m.header.stamp_nanos: m.tool_from_object for m in t["rig_world/ground_truth"]}
    stamps = np.array(sorted(truth))
    # The hold starts at the grasp monitor's stable grasp, a decision stamped by the data.
    # Not at the gripper's `holding`: the emulated WSG 50 reports it on the wall clock
    # (1.5 to 1.9 s into the scene in three runs under load) while the membranes still
    # settle around the mug, and the pose node rightly calls those frames' fits suspect.
    stable = next(
        (e.header.stamp_nanos - start) / 1e9 for e in t["supervisor/event"] if e.event == "stable"
    )

    def held_poses(recording: dict[str, list]) -> list:
        return [
            p
            for p in recording["pose/pose"]
            if p.status == "ok" and stable < (p.header.stamp_nanos - start) / 1e9 < PULL_SECS
        ]

    def assert_right(poses: list) -> None:
        for p in poses:
            near = stamps[np.argmin(np.abs(stamps - p.header.stamp_nanos))]
            axis_deg, offset_mm = pose_error(p.tool_from_object, truth[near])
            assert axis_deg < 3.0 and offset_mm < 2.0, (axis_deg, offset_mm)

    live = held_poses(t)
    assert live, "no pose ok while the mug was held"
    assert_right(live)

    # The recording replays in lockstep through the pose node and the task: the bag
    # decides, so every contact patch of the hold gets its pose, at the cameras' rate
    # whatever the machine's speed, and the task decides what it decided live.
    replayed = tmp_path / "replay.mcap"
    proc = launch(
        "replay", str(bag), "--swap", "pose", "--swap", "supervisor", "--lockstep",
        "--record", str(replayed),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:]
    r = topics(replayed)
    patches = [
        p
        for p in t["contact_patch/patch"]
        if len(p.points_in_tool) and stable < (p.header.stamp_nanos - start) / 1e9 < PULL_SECS
    ]
    held = held_poses(r)
    assert len(patches) >= 10 and len(held) >= 0.9 * len(patches), (len(held), len(patches))
    assert_right(held)
    again = [e.event for e in r["supervisor/event"]]
    assert again == names


FAULTS = """
rig: faulty
faults:
  - {device: gripper, at_secs: 0.5}
  - {device: left_camera, at_secs: 1.2, for_secs: 1.5}
  - {device: right_pressure, at_secs: 1.5, for_secs: 0.6}
"""


def test_faults_on_the_emulated_rig_are_named_recovered_and_recorded(tmp_path: Path) -> None:
    rig = tmp_path / "faulty.yaml"
    rig.write_text(FAULTS)
    bag = tmp_path / "faults.mcap"
    proc = launch("graphs/hardware.yaml", "--emulate", "--rig", str(rig), "--record", str(bag))
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    lines = out.splitlines()

    def first(pattern: str) -> tuple[int, str]:
        """The first line with ``pattern`` (a device may be reported again while the graph
        stops: the world's end closes the gripper's connection and silences the cameras)."""
        found = [(k, line) for k, line in enumerate(lines) if pattern in line]
        assert found, f"no line with {pattern!r}:\n{out[-3000:]}"
        return found[0]

    # Each fault: a line naming the device, then one when it recovered.
    faults = [
        ("[gripper] WARNING gripper: WSG 50 at 127.0.0.1", "connection lost", "reconnected after"),
        ("[left_camera] ", "'EMU-CAM-L' delivered no frame", "'EMU-CAM-L' is back after"),
        ("[right_pressure] ", "'EMU-BUBBLE-R': command 0x91: the bridge is gone", "'EMU-BUBBLE-R' is back"),
    ]  # fmt: skip
    for device, lost, back in faults:
        (k_lost, lost_line), (k_back, back_line) = first(lost), first(back)
        assert lost_line.startswith(device) and back_line.startswith(device), (lost_line, back_line)
        assert k_lost < k_back
    assert "handover: done" in out  # the task went on

    # The recording holds each device's data before its fault and after it recovered:
    # one gap in each stream, with messages on both sides. (Frames are stamped by the
    # world's clock; pressure and gripper states by the wall clock, which a loaded
    # machine's world lags behind, so each stream is judged by its own gaps.)
    t = topics(bag)

    def gap(topic: str, secs: float) -> None:
        stamps = np.array([m.header.stamp_nanos for m in t[topic]]) / 1e9
        steps = np.diff(stamps)
        k = int(np.argmax(steps))
        assert steps[k] >= secs and k >= 1 and len(stamps) - k - 1 >= 1, (topic, steps[k], k)

    gap("left_camera/image", 1.4)  # unplugged 1.5 s of world time
    gap("right_pressure/pressure", 0.5)  # unplugged 0.6 s
    start = t["rig_world/state"][0].header.stamp_nanos
    left = np.array([(m.header.stamp_nanos - start) / 1e9 for m in t["left_camera/image"]])
    assert not ((left > 1.25) & (left < 2.7)).any()  # no frame while unplugged
