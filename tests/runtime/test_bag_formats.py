"""Bag formats: a bag of the older multipart packing still reads; the schemas explain the new one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

import messages
import nodes.recorder  # noqa: F401  (registers the implementations the replay graph names)
import nodes.replay  # noqa: F401
from cli.run import launch
from messages.base import Header, Message
from messages.meaning import NOTES, unit_of
from messages.types import ContactPatch, OverlayImage, Pressure, Tick, ToFImage
from runtime.bag import PACKING, PACKING_V1, BagReader, BagWriter
from runtime.bag.schema import reader_guide
from runtime.replaygraph import ReplayOptions, build_replay_graph

V1_BAG = Path(__file__).parent / "data" / "bag_v1_multipart.mcap"
T0 = 1_763_900_000_000_000_000


def v1_expected() -> list[tuple[str, Message]]:
    """What ``V1_BAG`` holds, in file order: the script that wrote it (with the writer of the
    ``softbubble-multipart-v1`` packing, commit 075d7a3, zstd, a flush after the 2nd round)."""
    rng = np.random.default_rng(5)
    out: list[tuple[str, Message]] = []
    for i in range(4):
        depth = rng.uniform(0.04, 0.11, (6, 8)).astype(np.float32)
        depth[0, i] = np.nan
        ir = rng.integers(0, 60000, (6, 8)).astype(np.uint16)
        header = Header(stamp_nanos=T0 + i * 22_222_222, seq=i, frame_id="left_sensor")
        image = ToFImage(
            header=header,
            sensor="left",
            depth_m=depth,
            ir=ir,
            fx_px=210.0,
            fy_px=210.0,
            cx_px=3.5,
            cy_px=2.5,
        )
        pressure = Pressure(
            header=Header(stamp_nanos=T0 + i * 10_000_000, seq=i),
            sensor="left",
            pressure_pa=100.0 + i,
        )
        tick = Tick(
            header=Header(stamp_nanos=i, seq=i),
            value=i * 0.5,
            payload=np.arange(i, dtype=np.uint8),
        )
        out += [("left_camera/image", image), ("left_pressure/pressure", pressure)]
        out.append(("src/tick", tick))
    return out


def test_a_bag_of_the_multipart_packing_still_reads() -> None:
    expected = v1_expected()
    with BagReader(V1_BAG) as r:
        assert r.has_summary and not r.problems
        topics = r.topics()
        assert {s.packing for s in topics.values()} == {PACKING_V1}
        assert r.run_info()["command_line"] == "launch.py g.yaml --record v1.mcap"
        assert r.drops()["src/tick"]["runtime"] == 2
        got = list(r.messages())
        assert [m.topic for m in got] == [t for t, _ in expected]
        for m, (_, want) in zip(got, expected, strict=True):
            # Without today's classes: every field and array as recorded.
            plain = m.decode_plain()
            for name in ("depth_m", "ir", "payload"):
                if hasattr(want, name):
                    np.testing.assert_array_equal(plain[name], getattr(want, name))
            header = want.header  # type: ignore[attr-defined]
            assert plain["header"] == {
                "stamp_nanos": header.stamp_nanos,
                "seq": header.seq,
                "frame_id": header.frame_id,
            }
            # Into today's class: ToFImage has gained tool_from_sensor (with a default,
            # zeros: unknown) since this bag was recorded, so its messages decode too.
            typed = m.decode()
            assert type(typed) is type(want) and typed.header == header  # type: ignore[attr-defined]
            if isinstance(typed, ToFImage):
                assert m.channel.schema.fingerprint != ToFImage.schema().fingerprint
                assert not typed.tool_from_sensor.any()
                np.testing.assert_array_equal(typed.depth_m, want.depth_m)  # type: ignore[attr-defined]


def test_an_old_bag_replays_as_todays_types(tmp_path: Path) -> None:
    """Replay publishes the old ToFImage as today's (tool_from_sensor at its default), so
    every receiver decodes it; the recording of the replay holds today's fingerprint."""
    with BagReader(V1_BAG) as r:
        graph = yaml.safe_load(r.run_info()["graph_yaml"])
    out = tmp_path / "again.mcap"
    replay = build_replay_graph(graph, V1_BAG, {}, ReplayOptions(lockstep=True))
    assert launch(replay, source="replay", record=out, lockstep=True, log_level="WARNING") == 0
    expected = [want for topic, want in v1_expected() if topic == "left_camera/image"]
    with BagReader(out) as r:
        assert r.topics()["left_camera/image"].fingerprint == ToFImage.schema().fingerprint
        got = [m.decode() for m in r.messages(["left_camera/image"])]
        assert [m.header for m in got] == [w.header for w in expected]  # type: ignore[attr-defined]
        for m, want in zip(got, expected, strict=True):
            np.testing.assert_array_equal(m.depth_m, want.depth_m)  # type: ignore[attr-defined]
            assert not m.tool_from_sensor.any()  # type: ignore[attr-defined]


def test_recover_turns_an_old_bag_into_todays_packing(tmp_path: Path) -> None:
    from cli.bag import recover

    out = tmp_path / "v2.mcap"
    copied, skipped, problems = recover(V1_BAG, out)
    assert copied == 12 and skipped == [] and problems == []
    with BagReader(V1_BAG) as old, BagReader(out) as new:
        assert {s.packing for s in new.topics().values()} == {PACKING}
        for a, b in zip(old.messages(), new.messages(), strict=True):
            assert [bytes(f) for f in a.frames()] == [bytes(f) for f in b.frames()]
            assert (a.log_time_nanos, a.sequence) == (b.log_time_nanos, b.sequence)


def _stored_guide(path: Path, topic: str) -> dict:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (channel,) = [c for c in summary.channels.values() if c.topic == topic]
    return json.loads(summary.schemas[channel.schema_id].data)


def test_schema_says_what_a_message_holds(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    image = ToFImage(
        header=Header(stamp_nanos=T0, seq=1, frame_id="left_sensor"),
        sensor="left",
        depth_m=np.zeros((2, 3), np.float32),
        ir=np.zeros((2, 3), np.uint16),
        fx_px=1.0,
        fy_px=1.0,
        cx_px=1.0,
        cy_px=1.0,
    )
    overlay = OverlayImage(header=Header(), sensor="left", image=np.zeros((2, 3, 3), np.uint8))
    with BagWriter(path) as w:
        w.write_message("cam/image", image, log_time_nanos=1)
        w.write_message("shear/overlay", overlay, log_time_nanos=2)
    guide = _stored_guide(path, "cam/image")
    assert guide["packing"] == PACKING and "ONE MessagePack map" in guide["layout"]
    depth = guide["arrays"]["depth_m"]
    assert depth["dtype"] == "<f4" and depth["byte_order"] == "little"
    assert depth["order"].startswith("C") and depth["unit"] == "m" and "NaN" in depth["note"]
    assert guide["arrays"]["ir"]["dtype"] == "<u2"
    stamp = guide["fields"]["header.stamp_nanos"]
    assert stamp["type"] == "int64" and stamp["unit"] == "ns" and "2^53" in stamp["note"]
    assert guide["fields"]["fx_px"] == {"type": "float64", "unit": "px"}
    assert "frames" in guide["conventions"] and "poses" in guide["conventions"]
    pixels = _stored_guide(path, "shear/overlay")["arrays"]["image"]
    assert "B, G, R" in pixels["note"] and pixels["byte_order"].startswith("n/a")


def test_guide_of_every_message_type() -> None:
    """Units from names; poses explained; masks' 255 and patches' bubble index explained."""
    assert unit_of("speed_m_per_s") == "m/s" and unit_of("shear_mm") == "mm"
    assert unit_of("width_m") == "m" and unit_of("sensor") is None
    patch = reader_guide(ContactPatch.schema().description)
    assert "tool frame" in patch["arrays"]["points_in_tool"]["note"]
    assert "0 = left" in patch["arrays"]["bubble"]["note"]
    mask = reader_guide(messages.MaskImage.schema().description)
    assert "255" in mask["arrays"]["mask"]["note"]
    pose = reader_guide(messages.PoseEstimate.schema().description)
    assert "p_in_a = a_from_b" in pose["arrays"]["tool_from_object"]["note"]
    for cls in Message.registry.values():
        guide = reader_guide(cls.schema().description)
        assert set(guide["arrays"]) == set(cls.schema().array_fields)


@pytest.mark.parametrize("key", sorted(NOTES))
def test_every_note_names_a_declared_field(key: str) -> None:
    """A renamed field must take its note along."""
    type_name, _, name = key.rpartition(".")
    declared = {
        (cls.__name__, field)
        for cls in [*Message.registry.values(), Header]
        for field in cls.__struct_fields__
    }
    if type_name:
        assert (type_name, name) in declared
    else:
        assert any(field == name for _, field in declared)
