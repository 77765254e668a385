"""The viewer node, the bag commands and the mosaic, against a real short run of graph.yaml.

One recording for the module: ``launch.py graph.yaml --record BAG --view LIVE.rrd`` (the
default graph, a simulated mug handover that ends by itself in a few seconds), so the live
viewer node and the bag commands see the same messages.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from rerun.chunk import RrdReader

import launch
import nodes  # noqa: F401 - the index of node implementations
from cli.taps import add_viewer
from geometry.camera import PinholeCamera
from geometry.objects import NAMES, make
from messages.base import Header, Message
from messages.errors import GraphError
from messages.meaning import unit_of
from messages.types import ContactPatch, GraspState, PoseEstimate, ToFImage
from runtime.bag import BagReader, BagWriter
from runtime.graph import check, load_document
from viz.foxglove_export import convert, json_schema, to_json
from viz.mosaic import BAR_PX, LEGEND_PX, SIDES, MosaicState, depth_to_bgr, outline_px
from viz.shapes import object_mesh

ROOT = Path(__file__).resolve().parents[2]

# Message type -> an entity the Rerun logger must fill for it.
ENTITY_OF = {
    "ToFImage": "/tool/left_sensor/depth",
    "MaskImage": "/tool/left_sensor/mask/contact_patch",
    "ContactPatch": "/tool/patch",
    "PoseEstimate": "/pose/residual_rms_m",
    "GroundTruth": "/tool/object_true",
    "Pressure": "/pressure/left",
    "GripperState": "/gripper/force_n",
    "GraspState": "/grasp/stable",
    "ShearEstimate": "/tool/left_sensor/shear",
    "OverlayImage": "/overlay/left",
    "TaskEvent": "/events/task",
    "WrenchEstimate": "/wrench/object_force_n/z",
    "BubbleContact": "/contact/left/area_m2",
    "SlipState": "/slip/left/use",
}
NOT_DRAWN = {"WorldState", "GripperCommand"}


def rrd_rows(path: Path) -> Counter[str]:
    rows: Counter[str] = Counter()
    for chunk in RrdReader(path).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] += chunk.num_rows
    return rows


def bag_counts(path: Path) -> Counter[str]:
    with BagReader(path) as reader:
        return Counter(
            {topic: sum(1 for _ in reader.messages([topic])) for topic in reader.topics()}
        )


def bag_types(path: Path) -> dict[str, str]:
    with BagReader(path) as reader:
        return {t: s.type_name for t, s in reader.topics().items()}


def test_live_viewer_logs_every_stream(run: tuple[Path, Path]) -> None:
    bag, live = run
    rows = rrd_rows(live)
    types = set(bag_types(bag).values())
    assert types - NOT_DRAWN <= set(ENTITY_OF), f"a type with no entity to check: {types}"
    for kind in sorted(types - NOT_DRAWN):
        assert rows[ENTITY_OF[kind]] > 0, f"{kind}: nothing logged at {ENTITY_OF[kind]}"


def test_bag_view_logs_each_message_once(run: tuple[Path, Path], tmp_path: Path) -> None:
    bag, _ = run
    out = tmp_path / "bag.rrd"
    assert launch.main(["bag", "view", str(bag), "--out", str(out)]) == 0
    rows = rrd_rows(out)
    counts = bag_counts(bag)
    assert rows["/tool/left_sensor/depth"] == counts["left_camera/image"]
    assert rows["/tool/right_sensor/ir"] == counts["right_camera/image"]
    assert rows["/tool/patch"] == counts["contact_patch/patch"]
    assert rows["/pressure/left"] == counts["left_pressure/pressure"]
    assert rows["/events/task"] == counts["supervisor/event"]
    static = [c.entity_path for c in RrdReader(out).stream() if c.is_static]
    assert "/tool/object_true/mesh" in static


def _protobuf_class(schema: object) -> type:
    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)  # type: ignore[attr-defined]
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))  # type: ignore[attr-defined]


def test_foxglove_export_round_trips_image_and_cloud(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.02, 0.08, (6, 8)).astype(np.float32)
    depth[2, 3] = np.nan
    ir = rng.integers(0, 4000, (6, 8), dtype=np.uint16)
    image = ToFImage(
        header=Header(stamp_nanos=1_500_000_001, frame_id="left_sensor"),
        sensor="left",
        depth_m=depth,
        ir=ir,
        fx_px=7.0,
        fy_px=7.0,
        cx_px=3.5,
        cy_px=2.5,
    )
    points = rng.normal(0, 0.01, (50, 3)).astype(np.float32)
    bubble = (np.arange(50) % 2).astype(np.uint8)
    patch = ContactPatch(
        header=Header(stamp_nanos=1_500_000_002, frame_id="tool"),
        points_in_tool=points,
        bubble=bubble,
    )
    bag, out = tmp_path / "in.mcap", tmp_path / "fox.mcap"
    with BagWriter(bag) as writer:
        writer.write_message("left_camera/image", image, 1_500_000_001)
        writer.write_message("contact_patch/patch", patch, 1_500_000_002)
    assert launch.main(["bag", "export", str(bag), "--foxglove", str(out)]) == 0
    decoded: dict[str, tuple[str, Any]] = {}
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema.encoding == "protobuf":
                value = _protobuf_class(schema).FromString(message.data)
            else:
                value = json.loads(message.data)
            decoded[channel.topic] = (schema.name, value)
    names = {topic: name for topic, (name, _) in decoded.items()}
    assert names == {
        "/left_camera/image/depth": "foxglove.RawImage",
        "/left_camera/image/ir": "foxglove.RawImage",
        "/left_camera/image/calibration": "foxglove.CameraCalibration",
        "/contact_patch/patch": "foxglove.PointCloud",
    }
    got = decoded["/left_camera/image/depth"][1]
    assert (got.encoding, got.height, got.width, got.frame_id) == ("32FC1", 6, 8, "left_sensor")
    assert (got.timestamp.seconds, got.timestamp.nanos) == (1, 500_000_001)
    np.testing.assert_array_equal(np.frombuffer(got.data, np.float32).reshape(6, 8), depth)
    got_ir = decoded["/left_camera/image/ir"][1]
    np.testing.assert_array_equal(np.frombuffer(got_ir.data, "<u2").reshape(6, 8), ir)
    assert list(decoded["/left_camera/image/calibration"][1].K)[:3] == [7.0, 0.0, 3.5]
    cloud = decoded["/contact_patch/patch"][1]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "bubble"]
    assert cloud.frame_id == "tool"
    packed = np.frombuffer(cloud.data, np.uint8).reshape(-1, cloud.point_stride)
    np.testing.assert_array_equal(packed[:, :12].copy().view(np.float32), points)
    np.testing.assert_array_equal(packed[:, 12], bubble)


def test_video_has_one_frame_per_camera_instant(run: tuple[Path, Path], tmp_path: Path) -> None:
    bag, _ = run
    out, stills = tmp_path / "run.mp4", tmp_path / "stills"
    code = launch.main(
        ["bag", "video", str(bag), "--out", str(out), "--scale", "1", "--stills", str(stills)]
    )
    assert code == 0
    with BagReader(bag) as reader:
        first = next(reader.messages(["left_camera/image"])).decode()
        height, width = first.depth_m.shape
        stamps = {
            m.decode().header.stamp_nanos
            for m in reader.messages(["left_camera/image", "right_camera/image"])
        }
    video = cv2.VideoCapture(str(out))
    frames = 0
    while True:
        ok, frame = video.read()
        if not ok:
            break
        assert frame.shape == (BAR_PX + 3 * height, 2 * width + LEGEND_PX, 3)
        frames += 1
    video.release()
    assert frames == len(stamps)
    with BagReader(bag) as reader:
        said = [m.decode() for m in reader.messages(["supervisor/event"])]
        grasps = [m.decode().event for m in reader.messages(["grasp_monitor/grasp"])]
    events = len(said)
    pngs = sorted(stills.glob("*.png"))
    # first, last, one per task or grasp event, one each time the pose is tracked again
    assert 2 <= len(pngs) <= frames
    names = [re.fullmatch(r"run_(\d{5})_t(\d\d\.\d\d)s_(\w+)\.png", p.name) for p in pngs]
    assert all(names), [p.name for p in pngs]
    moments = [m.group(3) for m in names if m]
    assert "first" in moments[0] and "last" in moments[-1]
    # moments on one frame share its still, all named, sorted (a grasp's stable and the
    # task's answer to it are stamped alike)
    assert any(e.event == "release" for e in said) and "stable" in grasps, (said, grasps)
    assert any("handover_release" in m for m in moments), moments
    assert any("grasp_stable" in m for m in moments), moments
    assert sum(m.count("handover_") for m in moments) <= events
    for png in pngs:
        assert cv2.imread(str(png)).shape == (BAR_PX + 3 * height, 2 * width + LEGEND_PX, 3)


def test_bag_commands_name_a_bad_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "not_a_bag.mcap"
    bad.write_bytes(b"hello")
    assert launch.main(["bag", "video", str(bad), "--out", str(tmp_path / "x.mp4")]) == 2
    assert str(bad) in capsys.readouterr().err


def test_view_option_adds_a_viewer_on_every_topic() -> None:
    doc = load_document(ROOT / "graph.yaml")
    topics = set(check(doc).providers())
    viewed = add_viewer(doc, "out.rrd")
    node = viewed["nodes"]["viewer"]
    assert node["impl"] == "viewer.rerun" and node["params"] == {"target": "out.rrd"}
    assert {i["from"] for i in node["inputs"].values()} == topics
    assert add_viewer(doc, "foxglove")["nodes"]["viewer"]["impl"] == "viewer.foxglove"
    check(viewed)
    with pytest.raises(GraphError, match=r"node .viewer.\.params\.target: must be"):
        check(add_viewer(doc, "out.txt"))


@pytest.mark.parametrize("name", NAMES)
def test_object_meshes_span_the_field_bounds(name: str) -> None:
    mesh = object_mesh(name)
    assert mesh is not None and mesh.triangles.max() < len(mesh.vertices)
    lo, hi = make(name).bounds_m()
    np.testing.assert_allclose(mesh.vertices.min(0), lo, atol=2e-3)
    np.testing.assert_allclose(mesh.vertices.max(0), hi, atol=2e-3)
    assert object_mesh("no_such_object") is None


def test_outline_of_points_behind_the_camera_is_none() -> None:
    camera = PinholeCamera.from_fov()
    behind = np.array([[0.0, 0.0, -0.1], [0.01, 0.0, -0.1], [0.0, 0.01, -0.1]])
    assert outline_px(camera, behind) is None
    ahead = behind * np.array([1, 1, -1])
    hull = outline_px(camera, ahead)
    assert hull is not None and len(hull) == 3


def test_mosaic_draws_without_messages_and_with_nan_depth() -> None:
    state = MosaicState()
    assert state.render(scale=1).shape == (BAR_PX + 3 * 172, 2 * 224 + LEGEND_PX, 3)
    depth = np.full((4, 6), np.nan, np.float32)
    image = ToFImage(
        header=Header(stamp_nanos=5),
        sensor="left",
        depth_m=depth,
        ir=np.zeros((4, 6), np.uint16),
        fx_px=5.0,
        fy_px=5.0,
        cx_px=2.5,
        cy_px=1.5,
    )
    state.update("left_camera/image", image)
    frame = state.render(scale=1)
    assert frame.shape == (BAR_PX + 12, 12 + LEGEND_PX, 3) and np.isfinite(frame).all()
    assert frame.shape[:2] == state.size(scale=1)


def tof(depth_m: np.ndarray, side: str = "left") -> ToFImage:
    return ToFImage(
        header=Header(stamp_nanos=5, frame_id=f"{side}_sensor"),
        sensor=side,
        depth_m=depth_m.astype(np.float32),
        ir=np.zeros(depth_m.shape, np.uint16),
        fx_px=50.0,
        fy_px=50.0,
        cx_px=depth_m.shape[1] / 2,
        cy_px=depth_m.shape[0] / 2,
    )


def test_depth_colours_hold_one_range_for_a_whole_video() -> None:
    near = np.linspace(0.020, 0.030, 40 * 60).reshape(40, 60)
    far = near + 0.004  # a later frame: everything 4 mm further
    span = (0.020, 0.040)
    a, b = depth_to_bgr(near, span), depth_to_bgr(far, span)
    # The same depth (25 mm) has one colour in both frames...
    i = np.argmin(np.abs(near - 0.025))
    j = np.argmin(np.abs(far - 0.025))
    assert np.abs(a.reshape(-1, 3)[i].astype(int) - b.reshape(-1, 3)[j]).max() <= 12
    # ... where each frame's own range would have stretched both over the whole map.
    assert not np.array_equal(depth_to_bgr(near)[0, 0], a[-1, -1])


def test_mosaic_panels_are_labelled_and_the_legend_has_the_depth_bar() -> None:
    state = MosaicState(depth_span_m=(0.02, 0.04))
    depth = np.linspace(0.02, 0.04, 172 * 224).reshape(172, 224)
    for side in SIDES:
        state.update(f"{side}_camera/image", tof(depth, side))
    frame = state.render(scale=1, moment="grasp stable")
    for col in range(2):
        for row in range(3):
            y, x = BAR_PX + row * 172 + 4, col * 224 + 4
            assert (frame[y : y + 8, x : x + 30] == 20).all(axis=2).any()  # the label's box
    legend = frame[BAR_PX : BAR_PX + 172, 2 * 224 :]
    bar = legend[30:160, 8:18].astype(int)
    assert np.abs(bar[0] - bar[-1]).max() > 100  # the colour map runs down the bar
    assert (frame[:BAR_PX, -120:] != 32).any()  # the moment, on the bar's right


def test_foxglove_conversion_of_plain_messages() -> None:
    grasp = GraspState(header=Header(stamp_nanos=7), stable=True, event="stable")
    [(topic, kind, value)] = convert("grasp_monitor/grasp", grasp)
    assert (topic, kind) == ("grasp_monitor/grasp", "json")
    assert value["stable"] is True and value["header"]["stamp_nanos"] == 7
    empty = ContactPatch(
        header=Header(), points_in_tool=np.zeros((0, 3), np.float32), bubble=np.zeros(0, np.uint8)
    )
    assert [k for _, k, _ in convert("contact_patch/patch", empty)] == ["PointCloud"]
    assert "points_in_tool" in to_json(empty)


def pose(status: str) -> PoseEstimate:
    return PoseEstimate(
        header=Header(stamp_nanos=9, frame_id="tool"),
        tool_from_object=np.eye(4),
        residual_rms_m=0.0004,
        cost=1e-6,
        iterations=7,
        status=status,
        solve_secs=0.01,
        points_used=120,
        observable=[True] * 6,
    )


@pytest.mark.parametrize("status", ["ok", "recovered", "suspect", "no_patch", "failed"])
def test_foxglove_puts_a_pose_on_one_channel_and_tf(status: str) -> None:
    out = convert("pose/pose", pose(status))
    assert out[0][:2] == ("pose/pose", "json") and out[0][2]["status"] == status
    tracked = status in ("ok", "recovered")
    assert [(t, k) for t, k, _ in out[1:]] == ([("/tf", "FrameTransform")] if tracked else [])


@pytest.mark.parametrize("cls", sorted(Message.registry.values(), key=lambda c: c.__name__))
def test_foxglove_json_schemas_describe_fields_and_units(cls: type[Message]) -> None:
    schema = json_schema(cls)
    jsonschema.Draft202012Validator.check_schema(schema)
    fields = schema["properties"]
    assert set(fields) == set(cls.__struct_fields__)
    assert fields["header"]["properties"]["stamp_nanos"]["type"] == "integer"
    for name, field in fields.items():
        if unit_of(name):
            assert f"unit: {unit_of(name)}" in field["description"], name


def test_foxglove_json_of_a_pose_fits_its_schema() -> None:
    schema = json_schema(PoseEstimate)
    value = json.loads(json.dumps(to_json(pose("ok"))))
    jsonschema.validate(value, schema)
    assert schema["properties"]["residual_rms_m"]["description"].startswith("unit: m")
    assert "ok" in schema["properties"]["status"]["enum"]


def test_replay_shows_what_it_plays(run: tuple[Path, Path], tmp_path: Path) -> None:
    bag, _ = run
    out = tmp_path / "replay.rrd"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "launch.py", "replay", str(bag), "--fast", "--view", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = rrd_rows(out)
    counts = bag_counts(bag)
    assert rows["/tool/left_sensor/depth"] == counts["left_camera/image"]
    assert rows["/pressure/left"] == counts["left_pressure/pressure"]
