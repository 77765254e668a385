"""``bag export --ros2``: a ROS 2 bag (MCAP storage, CDR) read back with ``rosbags`` and
with ``mcap-ros2-support``, message by message, against the source bag."""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

import launch
from geometry.gripper import DEFAULT_GRIPPER, SIDES, tool_from_sensor
from geometry.se3 import make_pose, matrix_from_quat, rotation_about
from messages.base import Header
from messages.types import PoseEstimate, TaskEvent
from runtime.bag import BagReader, BagWriter
from viz.ros2_export import msg_definitions

STANDARD = {
    "/left_camera/image/depth": "sensor_msgs/msg/Image",
    "/left_camera/image/ir": "sensor_msgs/msg/Image",
    "/left_camera/image/camera_info": "sensor_msgs/msg/CameraInfo",
    "/contact_patch/patch": "sensor_msgs/msg/PointCloud2",
    "/pose/pose": "geometry_msgs/msg/PoseStamped",
    "/world/ground_truth": "geometry_msgs/msg/PoseStamped",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/pose/pose/full": "softbubble_msgs/msg/PoseEstimate",
    "/left_pressure/pressure": "softbubble_msgs/msg/Pressure",
    "/supervisor/event": "softbubble_msgs/msg/TaskEvent",
}


@pytest.fixture(scope="module")
def exported(run: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ros2") / "run_ros2"
    assert launch.main(["bag", "export", str(run[0]), "--ros2", str(out)]) == 0
    return out


def read_all(out: Path, expected: dict[str, str]) -> dict[str, list[tuple[int, Any]]]:
    """Every message of the ROS 2 bag, decoded by rosbags from the bag's own definitions;
    the ``expected`` topics carry their types."""
    got: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with AnyReader([out]) as reader:
        for connection, stamp, raw in reader.messages():
            got[connection.topic].append((stamp, reader.deserialize(raw, connection.msgtype)))
        types = {c.topic: c.msgtype for c in reader.connections}
    for topic, ros_type in expected.items():
        assert types.get(topic) == ros_type, topic
    return got


def pose_of(ros: Any) -> np.ndarray:
    q, p = ros.pose.orientation, ros.pose.position
    pose = np.eye(4)
    pose[:3, :3] = matrix_from_quat(np.array([q.w, q.x, q.y, q.z]))
    pose[:3, 3] = (p.x, p.y, p.z)
    return pose


def test_every_message_decodes_with_rosbags_and_matches_the_source(
    run: tuple[Path, Path], exported: Path
) -> None:
    with BagReader(run[0]) as reader:
        images = [m.decode() for m in reader.messages(["left_camera/image"])]
        poses = [m.decode() for m in reader.messages(["pose/pose"])]
        pressures = [m.decode() for m in reader.messages(["left_pressure/pressure"])]
        task_events = [m.decode() for m in reader.messages(["supervisor/event"])]
    tracked = [p for p in poses if p.status in ("ok", "recovered")]
    expected = {t: k for t, k in STANDARD.items() if tracked or t != "/pose/pose"}
    got = read_all(exported, expected)
    depth = got["/left_camera/image/depth"]
    assert len(depth) == len(images) and len(got["/left_camera/image/ir"]) == len(images)
    for (_, ros), ours in zip(depth, images, strict=True):
        assert ros.encoding == "32FC1" and (ros.height, ros.width) == ours.depth_m.shape
        assert ros.header.frame_id == "left_sensor"
        assert ros.header.stamp.sec * 10**9 + ros.header.stamp.nanosec == ours.header.stamp_nanos
        assert ros.data.tobytes() == ours.depth_m.astype("<f4").tobytes()  # NaN too
    for (_, ros), ours in zip(got["/left_camera/image/ir"], images, strict=True):
        assert ros.encoding == "mono16"
        assert np.array_equal(ros.data.view("<u2").reshape(ours.ir.shape), ours.ir)
    info = got["/left_camera/image/camera_info"][0][1]
    assert info.k[0] == images[0].fx_px and info.k[2] == images[0].cx_px
    assert len(got["/pose/pose"]) == len(tracked)
    assert len(got["/pose/pose/full"]) == len(poses)
    for (_, ros), ours in zip(got["/pose/pose"], tracked, strict=True):
        assert ros.header.frame_id == "tool"
        np.testing.assert_allclose(pose_of(ros), ours.tool_from_object, atol=1e-12)
    for (_, ros), ours in zip(got["/pose/pose/full"], poses, strict=True):
        assert isinstance(ours, PoseEstimate)
        assert ros.status == ours.status and ros.residual_rms_m == ours.residual_rms_m
        assert ros.seq == ours.header.seq and list(ros.observable) == list(ours.observable)
        np.testing.assert_array_equal(ros.tool_from_object.reshape(4, 4), ours.tool_from_object)
    assert [r.pressure_pa for _, r in got["/left_pressure/pressure"]] == [
        p.pressure_pa for p in pressures
    ]
    # A task event's typed record (the summary's) travels as its JSON.
    assert any(e.data is not None for e in task_events)
    for (_, ros), ours in zip(got["/supervisor/event"], task_events, strict=True):
        assert isinstance(ours, TaskEvent) and ros.event == ours.event
        assert json.loads(ros.data) == msgspec.to_builtins(ours.data)
    patch = got["/contact_patch/patch"][-1][1]
    assert [f.name for f in patch.fields] == ["x", "y", "z", "bubble"]


def test_tracked_poses_become_pose_stamped_and_tf(tmp_path: Path) -> None:
    rotation = make_pose(rotation_about(np.array([0.3, 0.2, 0.9]), 0.7), [0.01, -0.02, 0.05])
    statuses = ["no_patch", "ok", "suspect", "recovered"]
    bag, out = tmp_path / "poses.mcap", tmp_path / "poses_ros2"
    with BagWriter(bag) as writer:
        for i, status in enumerate(statuses):
            pose = PoseEstimate(
                header=Header(stamp_nanos=(i + 1) * 10**8, seq=i, frame_id="tool"),
                tool_from_object=rotation,
                residual_rms_m=1e-4 * i,
                cost=0.0,
                iterations=3,
                status=status,
                solve_secs=0.01,
                points_used=100,
            )
            writer.write_message("pose/pose", pose, (i + 1) * 10**8)
    assert launch.main(["bag", "export", str(bag), "--ros2", str(out)]) == 0
    got = read_all(
        out, {"/pose/pose": "geometry_msgs/msg/PoseStamped", "/tf": "tf2_msgs/msg/TFMessage"}
    )
    stamped = [m for _, m in got["/pose/pose"]]
    assert len(stamped) == 2  # ok and recovered
    for ros in stamped:
        np.testing.assert_allclose(pose_of(ros), rotation, atol=1e-12)
    children = [t.child_frame_id for _, m in got["/tf"] for t in m.transforms]
    assert children == ["object_estimate", "object_estimate"]
    assert [m.status for _, m in got["/pose/pose/full"]] == statuses


def test_the_tf_tree_puts_the_cameras_where_the_images_say(exported: Path) -> None:
    got = read_all(exported, {"/tf": "tf2_msgs/msg/TFMessage"})
    (static,) = [m for _, m in got["/tf_static"]]
    mounts = {t.child_frame_id: t for t in static.transforms}
    assert set(mounts) == {"left_sensor", "right_sensor"}
    fingers = [
        t for _, m in got["/tf"] for t in m.transforms if t.child_frame_id.endswith("finger")
    ]
    assert {t.child_frame_id for t in fingers} == {"left_finger", "right_finger"}
    assert {t.header.frame_id for t in fingers} == {"tool"}
    width = 0.07
    for side in SIDES:
        chain = DEFAULT_GRIPPER.tool_from_finger(side, width) @ DEFAULT_GRIPPER.finger_from_sensor()
        np.testing.assert_allclose(chain, tool_from_sensor(side, width), atol=1e-12)


def test_mcap_ros2_support_reads_every_message(run: tuple[Path, Path], exported: Path) -> None:
    (mcap_file,) = exported.glob("*.mcap")
    counts: Counter[str] = Counter()
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, ros_msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            assert ros_msg is not None
    with AnyReader([exported]) as reader:
        assert sum(counts.values()) == reader.message_count
    with BagReader(run[0]) as reader:
        stats = reader.stats()
    assert counts["/left_pressure/pressure"] == stats["left_pressure/pressure"].messages
    assert counts["/left_camera/image/depth"] == stats["left_camera/image"].messages


def test_project_types_become_msg_definitions_with_units() -> None:
    text = msg_definitions(PoseEstimate)["softbubble_msgs/msg/PoseEstimate"]
    lines = text.splitlines()
    assert lines[:2] == ["std_msgs/Header header", "uint64 seq  # per-output sequence number"]
    assert any(line.startswith("float64[16] tool_from_object  # shape [4, 4]") for line in lines)
    assert "float64 residual_rms_m  # m" in lines
    assert any(line.startswith("string status  # one of: ok, recovered") for line in lines)
    assert "bool[] observable" in " ".join(lines)


def test_export_refuses_an_existing_folder_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not a bag")
    assert launch.main(["bag", "export", str(bad), "--ros2", str(tmp_path / "out")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]
    (tmp_path / "out").mkdir()
    assert launch.main(["bag", "export", str(bad), "--ros2", str(tmp_path / "out")]) == 2
    assert "exists" in capsys.readouterr().err
