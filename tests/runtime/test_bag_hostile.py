"""Damaged and altered bags: every bag tool skips what it cannot use and says how many (or
stops with a non-zero exit, as docs/bags.md says), never a traceback; nothing writes onto
the bag it reads."""

from __future__ import annotations

import functools
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import runtime.bag.writer as writer_module
from messages.base import Header
from messages.errors import BagError
from messages.types import Pressure, Tick, ToFImage
from runtime.bag import BagReader, BagWriter, TopicSchema
from tests.launching import launch_py
from tests.runtime.bad_bags import MS, bag_with_undecodable
from tests.synthetic_nodes import IMPLS

ROOT = Path(__file__).resolve().parents[2]


launch = functools.partial(launch_py, timeout=120)


def no_traceback(result: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in result.stdout + result.stderr, result.stdout + result.stderr


def replayable_bag(path: Path) -> Path:
    graph = (
        f"nodes:\n  src: {{impl: '{IMPLS['synthetic.source']}'}}\n"
        f"  sink: {{impl: '{IMPLS['synthetic.sink']}', inputs: {{tick: src/tick}}}}\n"
    )
    with BagWriter(path) as writer:
        writer.add_run_info(graph_text=graph, graph_source="g.yaml")
        for i in range(20):
            tick = Tick(header=Header(stamp_nanos=i * MS, seq=i), value=float(i))
            writer.write_message("src/tick", tick, log_time_nanos=i * 10 * MS)
    return path


@pytest.mark.parametrize("how", ["same path", "symlink", "hard link"])
def test_replay_refuses_to_record_onto_its_own_input(tmp_path: Path, how: str) -> None:
    bag = replayable_bag(tmp_path / "run.mcap")
    before = bag.read_bytes()
    out = bag
    if how == "symlink":
        out = tmp_path / "link.mcap"
        out.symlink_to(bag)
    elif how == "hard link":
        out = tmp_path / "other.mcap"
        os.link(bag, out)
    result = launch("replay", bag, "--fast", "--record", out, "--overwrite")
    no_traceback(result)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "is the bag being replayed" in result.stderr
    assert bag.read_bytes() == before


def test_bag_echo_skips_a_wrongly_typed_field_and_exits_1(tmp_path: Path) -> None:
    bag = bag_with_undecodable(tmp_path / "b.mcap", 5, {2: "field"})
    result = launch("bag", "echo", bag, "--topic", "a/tick")
    no_traceback(result)
    assert result.returncode == 1, result.stdout + result.stderr
    skipped = [line for line in result.stdout.splitlines() if "SKIPPED" in line]
    assert len(skipped) == 1 and "#2 " in skipped[0] and "'value'" in skipped[0], result.stdout
    assert "not a number" not in result.stdout.replace(skipped[0], "")  # never printed as data
    assert result.stdout.count("value: ") == 4
    assert "1 message(s) could not be decoded" in result.stderr


def test_bag_recover_goes_on_past_bad_messages(tmp_path: Path) -> None:
    bag = bag_with_undecodable(tmp_path / "b.mcap", 60, {3: "cut", 10: "field", 40: "cut"})
    out = tmp_path / "fixed.mcap"
    result = launch("bag", "recover", bag, out)
    no_traceback(result)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "57 message(s) recovered" in result.stdout
    assert "3 message(s) could not be decoded and were left out" in result.stderr
    with BagReader(out) as reader:
        values = [m.decode().value for m in reader.messages()]  # type: ignore[attr-defined]
    assert values == [float(i) for i in range(60) if i not in (3, 10, 40)]


def test_bag_recover_refuses_its_input_by_another_name(tmp_path: Path) -> None:
    bag = bag_with_undecodable(tmp_path / "b.mcap", 5, {})
    before = bag.read_bytes()
    os.link(bag, tmp_path / "same.mcap")
    result = launch("bag", "recover", bag, tmp_path / "same.mcap")
    assert result.returncode == 2 and "give another output path" in result.stderr
    assert bag.read_bytes() == before


def damaged_camera_bag(path: Path) -> Path:
    """Six camera images and pressures; image 2 has a NaN focal length and depth, image 4 a
    stamp beyond what a Foxglove time holds, pressure 3 is NaN."""
    with BagWriter(path) as writer:
        for i in range(6):
            stamp = (i + 1) * 33 * MS
            fx = float("nan") if i == 2 else 5.0
            image = ToFImage(
                header=Header(stamp_nanos=2**63 - 1 if i == 4 else stamp, frame_id="left_sensor"),
                sensor="left",
                depth_m=np.full((4, 6), float("nan") if i == 2 else 0.05, np.float32),
                ir=np.zeros((4, 6), np.uint16),
                fx_px=fx,
                fy_px=5.0,
                cx_px=3.0,
                cy_px=2.0,
            )
            writer.write_message("left_camera/image", image, stamp)
            pa = float("nan") if i == 3 else 1000.0
            pressure = Pressure(header=Header(stamp_nanos=stamp), sensor="left", pressure_pa=pa)
            writer.write_message("left/pressure", pressure, stamp)
    return path


@pytest.mark.parametrize(
    ("command", "out", "skipped"),
    [
        ("export", "--foxglove", "1 ToFImage message(s) with values that cannot be used"),
        ("video", "--out", "1 ToFImage message(s) with values that cannot be used"),
    ],
)
def test_bag_view_tools_skip_and_count_damaged_messages(
    tmp_path: Path, command: str, out: str, skipped: str
) -> None:
    bag = damaged_camera_bag(tmp_path / "damaged.mcap")
    target = tmp_path / ("out.mp4" if command == "video" else "out.mcap")
    result = launch("bag", command, bag, out, target)
    no_traceback(result)
    assert result.returncode == 1, result.stdout + result.stderr
    assert skipped in result.stderr
    assert target.exists()


def test_bag_video_skips_an_undecodable_camera_image(tmp_path: Path) -> None:
    bag = damaged_camera_bag(tmp_path / "damaged.mcap")
    real = writer_module.pack_single
    written = [0]

    def cut_third(frames: object) -> bytes:
        data = real(frames)
        written[0] += 1
        return data[:-3] if written[0] == 3 else data

    cut = tmp_path / "cut.mcap"
    with pytest.MonkeyPatch.context() as patch, BagReader(bag) as reader:
        patch.setattr(writer_module, "pack_single", cut_third)
        with BagWriter(cut) as writer:
            for msg in reader.messages():
                writer.copy_message(msg)
    result = launch("bag", "video", cut, "--out", tmp_path / "v.mp4")
    no_traceback(result)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "not decodable today; skipped" in result.stderr


def test_a_stored_schema_edited_under_its_fingerprint_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    description = Tick.schema().description
    edited = {**description, "fields": [f for f in description["fields"] if f[0] != "value"]}

    def tampered(type_name: str, fingerprint: str) -> TopicSchema:
        return TopicSchema(type_name, fingerprint, edited)  # today's fingerprint, kept

    monkeypatch.setattr(writer_module, "schema_for", tampered)
    bag = tmp_path / "edited.mcap"
    with BagWriter(bag) as writer:
        for i in range(3):
            writer.write_message("a/tick", Tick(header=Header(seq=i), value=1.5), i * MS)
    monkeypatch.undo()
    warnings: list[str] = []
    with BagReader(bag, warn=warnings.append) as reader:
        assert any("does not match its fingerprint" in w for w in warnings), warnings
        for msg in reader.messages():
            with pytest.raises(BagError, match="does not match its fingerprint"):
                msg.decode()
            with pytest.raises(BagError, match="does not match its fingerprint"):
                msg.decode_plain()
    result = launch("bag", "echo", bag, "--topic", "a/tick")
    assert result.returncode == 1 and result.stdout.count("SKIPPED") == 3, result.stdout
