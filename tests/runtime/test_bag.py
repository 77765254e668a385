"""The MCAP bag layer: round trip, foreign readers, recovery, corruption, clear errors."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
from pathlib import Path
from typing import Annotated

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from messages.base import Array, Header, Message
from messages.codec import encode
from messages.errors import BagError, SchemaChangeError
from messages.types import Tick, ToFImage
from runtime.bag import PACKING, BagReader, BagWriter
from runtime.bag.packing import unpack_multipart
from tests.messages.declare import declare

ROOT = Path(__file__).resolve().parents[2]


def tof(i: int, sensor: str = "left") -> ToFImage:
    rng = np.random.default_rng(i)
    depth = rng.uniform(0.04, 0.11, (17, 22)).astype(np.float32)
    depth[0, :3] = np.nan
    return ToFImage(
        header=Header(stamp_nanos=1_000 + i, seq=i, frame_id=f"{sensor}_sensor"),
        sensor=sensor,
        depth_m=depth,
        ir=rng.integers(0, 60000, (17, 22)).astype(np.uint16),
        fx_px=200.0,
        fy_px=201.0,
        cx_px=11.0,
        cy_px=8.5,
    )


def tick(i: int) -> Tick:
    return Tick(header=Header(stamp_nanos=5_000 + i, seq=i), value=float(i))


def write_chunks(path: Path, chunks: int, per_chunk: int, **kwargs: object) -> None:
    """A bag with ``chunks`` chunks of ``per_chunk`` ticks each (explicit flushes)."""
    with BagWriter(path, **kwargs) as w:  # type: ignore[arg-type]
        w.add_run_info(graph_text="nodes: {a: {impl: x}}\n", command_line="launch.py g.yaml")
        n = 0
        for _ in range(chunks):
            for _ in range(per_chunk):
                w.write_message("a/tick", tick(n), log_time_nanos=n * 1_000_000)
                n += 1
            w.flush()


def test_round_trip_typed_and_plain(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    sent = [tof(i, s) for i in range(5) for s in ("left", "right")]
    with BagWriter(path, compression="zstd") as w:
        w.add_run_info(graph_text="nodes: {}\n", graph_source="g.yaml", command_line="x y")
        for i, msg in enumerate(sent):
            w.write_message(f"{msg.sensor}_camera/image", msg, log_time_nanos=i * 10)
        w.write_message("src/tick", tick(0), log_time_nanos=99)
    with BagReader(path) as r:
        assert r.has_summary and not r.problems
        topics = r.topics()
        assert set(topics) == {"left_camera/image", "right_camera/image", "src/tick"}
        assert topics["src/tick"].type_name == "Tick"
        assert topics["left_camera/image"].fingerprint == ToFImage.schema().fingerprint
        assert topics["left_camera/image"].description == ToFImage.schema().description
        assert r.run_info()["graph_yaml"] == "nodes: {}\n"
        assert r.run_info()["command_line"] == "x y"
        got = list(r.messages(["left_camera/image", "right_camera/image"]))
        assert [m.log_time_nanos for m in got] == [i * 10 for i in range(10)]
        for m, want in zip(got, sent, strict=True):
            typed = m.decode()
            assert isinstance(typed, ToFImage)
            np.testing.assert_array_equal(typed.depth_m, want.depth_m)
            np.testing.assert_array_equal(typed.ir, want.ir)
            plain = m.decode_plain()
            assert plain["sensor"] == want.sensor and plain["fx_px"] == 200.0
            assert plain["header"]["seq"] == want.header.seq
            np.testing.assert_array_equal(plain["ir"], want.ir)
            assert m.publish_time_nanos == want.header.stamp_nanos
            assert m.sequence == want.header.seq
        stats = r.stats()
        assert stats["left_camera/image"].messages == 5 and stats["src/tick"].messages == 1


def test_arrays_are_stored_as_received(tmp_path: Path) -> None:
    """The payload is the wire frames byte for byte behind a small frame table."""
    path = tmp_path / "a.mcap"
    frames = encode("c/image", tof(3))
    with BagWriter(path) as w:
        w.write_frames("c/image", frames, log_time_nanos=1)
    with BagReader(path) as r:
        (m,) = r.messages()
        stored = m.frames()
    assert [bytes(f) for f in stored] == [bytes(memoryview(f).cast("B")) for f in frames[1:]]


_OUTLIVES_READER = """
import sys
import numpy as np
from runtime.bag import BagReader
with BagReader(sys.argv[1]) as r:
    (m,) = r.messages()
    depth = m.decode().depth_m
    del m
print(np.nansum(depth))
with BagReader(sys.argv[1]) as r:
    depth = next(iter(r.messages())).decode_plain()["depth_m"]
print(np.nansum(depth))
"""


def test_decoded_arrays_outlive_the_reader(tmp_path: Path) -> None:
    """A typed array is a view on the mapped file; closing the reader must not unmap it
    under the array (run in a child: a dangling view is a segmentation fault)."""
    path = tmp_path / "a.mcap"
    msg = tof(1)
    with BagWriter(path) as w:
        w.write_message("c/image", msg, log_time_nanos=1)
    done = subprocess.run(
        [sys.executable, "-c", _OUTLIVES_READER, str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).parents[2],
    )
    assert done.returncode == 0, done.stderr
    typed, plain = (float(x) for x in done.stdout.split())
    assert typed == plain == pytest.approx(float(np.nansum(msg.depth_m)))


_THIRD_PARTY_READER = """
import json, sys
import msgpack
import numpy as np
from mcap.reader import make_reader
out = []
with open(sys.argv[1], "rb") as f:
    for schema, channel, message in make_reader(f).iter_messages():
        value = msgpack.unpackb(message.data)  # one value: the whole message
        arrays = {
            name: np.frombuffer(a["data"], dtype=a["dtype"]).reshape(a["shape"], order=a["order"])
            for name, a in value["arrays"].items()
        }
        guide = json.loads(schema.data)
        out.append({
            "topic": channel.topic, "encoding": channel.message_encoding,
            "schema": schema.name, "fingerprint": guide["fingerprint"],
            "type": value["type"], "seq": value["fields"]["header"]["seq"],
            "stamp_nanos": value["fields"]["header"]["stamp_nanos"],
            "fx_px": value["fields"]["fx_px"],
            "depth_unit": guide["arrays"]["depth_m"]["unit"],
            "depth_m": [[None if np.isnan(x) else float(x) for x in row] for row in arrays["depth_m"]],
            "ir": arrays["ir"].tolist(),
        })
print(json.dumps(out))
"""


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_plain_mcap_reader_and_msgpack_need_no_project_code(
    tmp_path: Path, compression: str
) -> None:
    """The ``mcap`` package and ``msgpack.unpackb`` alone recover every field and array."""
    path = tmp_path / "a.mcap"
    sent = [tof(i) for i in range(3)]
    for i, msg in enumerate(sent):
        msg.header.stamp_nanos = 1_763_900_000_123_456_789 + i  # past 2^53, as a wall clock
    with BagWriter(path, compression=compression) as w:
        for i, msg in enumerate(sent):
            w.write_message("left_camera/image", msg, log_time_nanos=i)
    # Isolated (-I) and run from an empty folder, so nothing of the project can be imported.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-I", "-c", _THIRD_PARTY_READER, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    import json

    rows = json.loads(done.stdout)
    assert len(rows) == 3
    for i, (row, want) in enumerate(zip(rows, sent, strict=True)):
        assert row["topic"] == "left_camera/image" and row["encoding"] == "msgpack"
        assert row["schema"] == row["type"] == "ToFImage"
        assert row["fingerprint"] == ToFImage.schema().fingerprint
        assert row["seq"] == i and row["stamp_nanos"] == want.header.stamp_nanos
        assert row["fx_px"] == 200.0 and row["depth_unit"] == "m"
        depth = np.array([[np.nan if x is None else x for x in r] for r in row["depth_m"]])
        np.testing.assert_array_equal(depth.astype(np.float32), want.depth_m)
        np.testing.assert_array_equal(row["ir"], want.ir)


def test_header_decodes_with_plain_msgpack(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        w.write_message("a/tick", tick(7), log_time_nanos=1)
    with BagReader(path) as r:
        (m,) = r.messages()
        head = msgpack.unpackb(bytes(m.frames()[0]), raw=False)
    assert head["type"] == "Tick"
    assert head["fp"] == Tick.schema().fingerprint
    assert head["fields"]["value"] == 7.0
    assert head["arrays"] == [["payload", "|u1", [0]]]


def test_multipart_v1_payload_must_match_its_frame_table() -> None:
    payload = struct.pack("<I2Q", 2, 3, 4) + b"abcdefg"
    assert [bytes(f) for f in unpack_multipart(payload)] == [b"abc", b"defg"]
    with pytest.raises(ValueError, match="frame table"):
        unpack_multipart(payload[:-1])
    with pytest.raises(ValueError):
        unpack_multipart(b"\x01")


class BagTestOldTick(Message):
    """A type that will not exist when the bag is read back (removed from the registry)."""

    header: Header
    temperature_k: float
    samples: Annotated[np.ndarray, Array("float32", (None,))]


def test_old_bag_decodes_without_todays_class(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    old = BagTestOldTick(
        header=Header(seq=4), temperature_k=300.5, samples=np.arange(3, dtype=np.float32)
    )
    with BagWriter(path) as w:
        w.write_message("probe/old", old, log_time_nanos=1)
    fingerprint = BagTestOldTick.schema().fingerprint
    del Message.registry["BagTestOldTick"]  # "the field changed": today's code lacks the class
    try:
        with BagReader(path) as r:
            schema = r.topics()["probe/old"]
            assert schema.type_name == "BagTestOldTick" and schema.fingerprint == fingerprint
            assert [f[0] for f in schema.description["fields"]] == [
                "header",
                "temperature_k",
                "samples",
            ]
            with pytest.raises(SchemaChangeError, match="BagTestOldTick is not declared today"):
                schema.current_class()
            (m,) = r.messages()
            plain = m.decode_plain()
            assert plain["temperature_k"] == 300.5
            np.testing.assert_array_equal(plain["samples"], [0.0, 1.0, 2.0])
            with pytest.raises(
                BagError, match=r"old\.mcap: topic probe/old: message at offset \d+"
            ):
                m.decode()
    finally:
        Message.registry["BagTestOldTick"] = BagTestOldTick


def test_a_field_removed_since_the_recording_is_refused_by_name(
    tmp_path: Path, scratch_registry: dict
) -> None:
    """The other side of schema evolution (``messages.evolution``): a bag whose type lost a
    field since is refused by the typed decode and by replay, naming type and field."""
    from nodes.replay import ReplayParams, replay_topics

    path = tmp_path / "old.mcap"
    fields = [("header", Header), ("value", float), ("gain", float, 1.0)]
    old = declare("BagTestEvolving", fields, keep=True)
    with BagWriter(path) as w:
        w.write_message("probe/evolving", old(header=Header(seq=1), value=2.0), log_time_nanos=1)
    del scratch_registry["BagTestEvolving"]
    declare("BagTestEvolving", fields[:2], keep=True)  # today: "gain" is gone
    with BagReader(path) as r:
        (m,) = r.messages()
        assert m.decode_plain()["gain"] == 1.0  # the plain read still has it all
        why = r"BagTestEvolving\.gain: stored, but today's BagTestEvolving has no such field"
        with pytest.raises(SchemaChangeError, match=why):
            r.topics()["probe/evolving"].current_class()
        with pytest.raises(BagError, match=r"old\.mcap: topic probe/evolving: .*" + why):
            m.decode()
    with pytest.raises(ValueError, match=r"old\.mcap: topic probe/evolving: channel at .*" + why):
        replay_topics(ReplayParams(path=str(path)))


def test_not_mcap_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_bytes(b"this is not a bag at all, just text\n")
    with pytest.raises(BagError, match=r"notes\.txt: not an MCAP file"):
        BagReader(path)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(BagError, match=r"empty\.mcap: not an MCAP file"):
        BagReader(empty)
    with pytest.raises(BagError, match="cannot open"):
        BagReader(tmp_path / "missing.mcap")


def test_topic_not_in_bag_names_file_and_topic(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    write_chunks(path, 1, 2)
    with BagReader(path) as r, pytest.raises(BagError, match=r"a\.mcap: topic 'b/tick' is not in"):
        r.require_topics(["b/tick"])


def test_malformed_frames_are_counted_not_stored(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    good = encode("c/image", tof(1))
    with BagWriter(path) as w:
        assert not w.write_frames("c/image", [b"c/image", b"\xc1garbage"], log_time_nanos=1)
        assert not w.write_frames("c/image", [*good[:-1], b"short"], log_time_nanos=2)
        assert w.write_frames("c/image", good, log_time_nanos=3)
    with BagReader(path) as r:
        assert len(list(r.messages())) == 1
        assert r.drops()["c/image"]["rejected"] == 2


def test_drops_and_seq_gaps_are_in_the_bag(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        for seq in (0, 1, 4, 5, 9):
            w.write_message("a/tick", Tick(header=Header(seq=seq)), log_time_nanos=seq)
        w.set_runtime_drops({"a/tick": 6})
    with BagReader(path) as r:
        assert r.drops() == {"a/tick": {"runtime": 6, "seq_gaps": 5, "rejected": 0}}
        assert r.stats()["a/tick"].seq_gaps == 5


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_truncated_file_is_recovered(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "a.mcap"
    write_chunks(path, 4, 5, compression=compression)
    with BagReader(path) as r:
        chunk_offsets = [c.offset for c in r.chunks]
        assert len(chunk_offsets) == 4
    data = path.read_bytes()
    cases = {
        "in the last chunk": (chunk_offsets[3] + 40, 15),
        "right after the third chunk's indexes": (chunk_offsets[3], 15),
        "in the summary": (len(data) - 40, 20),
    }
    for what, (cut, expect) in cases.items():
        cut_path = tmp_path / "cut.mcap"
        cut_path.write_bytes(data[:cut])
        problems: list[str] = []
        with BagReader(cut_path, warn=problems.append) as r:
            values = [m.decode_plain()["value"] for m in r.messages()]
            assert not r.has_summary, what
        assert values == [float(i) for i in range(expect)], what
        assert any("interrupted" in p for p in problems), what


def test_bag_info_of_truncated_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cli.main import main

    path = tmp_path / "a.mcap"
    write_chunks(path, 3, 4)
    with BagReader(path) as r:
        cut = r.chunks[2].offset + 30
    path.write_bytes(path.read_bytes()[:cut])
    assert main(["bag", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "summary:   NO" in out
    assert "a/tick" in out and " 8 " in out
    assert f"offset {cut - 30}" in out  # where the file stops making sense


def _flip(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("compression", ["none", "zstd", "lz4"])
def test_corrupt_chunk_is_skipped_with_count(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "a.mcap"
    write_chunks(path, 3, 6, compression=compression)
    with BagReader(path) as r:
        second = r.chunks[1]
    _flip(path, second.offset + second.length - 20)  # inside the chunk's records
    problems: list[str] = []
    with BagReader(path, warn=problems.append) as r:
        values = [m.decode_plain()["value"] for m in r.messages()]
        assert r.lost_messages == 6
    assert values == [float(i) for i in [*range(6), *range(12, 18)]]
    assert len(problems) == 1
    assert f"corrupt chunk at offset {second.offset}" in problems[0]
    assert "6 message(s) lost" in problems[0] and "a.mcap" in problems[0]


@pytest.mark.parametrize("with_summary", [True, False])
def test_broken_record_framing_resyncs_at_next_chunk(tmp_path: Path, with_summary: bool) -> None:
    path = tmp_path / "a.mcap"
    write_chunks(path, 3, 4)
    with BagReader(path) as r:
        second, third = r.chunks[1], r.chunks[2]
        end_of_data = third.offset + third.length
    _flip(path, second.offset)  # the opcode byte: the record no longer makes sense
    if not with_summary:
        path.write_bytes(path.read_bytes()[: end_of_data + 200])
    problems: list[str] = []
    with BagReader(path, warn=problems.append) as r:
        values = [m.decode_plain()["value"] for m in r.messages()]
    assert values[:4] == [0.0, 1.0, 2.0, 3.0]
    assert values[4:8] == [8.0, 9.0, 10.0, 11.0]
    assert any(f"broken record at offset {second.offset}" in p for p in problems)


_KILLED_WRITER = """
import sys, time
from messages.base import Header
from messages.types import Tick
from runtime.bag import BagWriter
w = BagWriter(sys.argv[1], flush_period_secs=float(sys.argv[2]))
i = 0
while True:
    now = time.monotonic_ns()
    w.write_message("a/tick", Tick(header=Header(seq=i), value=float(i)), log_time_nanos=now)
    print(i, now, flush=True)
    i += 1
    time.sleep(0.002)
"""


def test_sigkilled_writer_keeps_everything_older_than_the_flush_period(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    period = 0.1
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path), str(period)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    seen: list[tuple[int, int]] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            index, stamp = (int(x) for x in line.split())
            seen.append((index, stamp))
            if stamp - seen[0][1] > 4 * period * 1e9 and len(seen) > 20:
                break
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    last_stamp = seen[-1][1]
    must_have = [i for i, stamp in seen if stamp <= last_stamp - period * 1e9]
    assert must_have, "the writer did not run long enough"
    with BagReader(path) as r:
        assert not r.has_summary
        got = [int(m.decode_plain()["value"]) for m in r.messages()]
    assert got == list(range(len(got))), "recovered messages are in order, none skipped"
    assert len(got) >= len(must_have)


def test_channel_copies_survive_a_corrupt_first_chunk(tmp_path: Path) -> None:
    """Channels are also written as metadata outside the chunks, so later chunks still decode."""
    path = tmp_path / "a.mcap"
    write_chunks(path, 2, 3)
    with BagReader(path) as r:
        first = r.chunks[0]
    _flip(path, first.offset + first.length - 10)
    with BagReader(path, warn=lambda _: None) as r:
        values = [m.decode_plain()["value"] for m in r.messages()]
        assert r.lost_messages == 3
    assert values == [3.0, 4.0, 5.0]


def test_schema_record_carries_description(tmp_path: Path) -> None:
    import json

    from mcap.reader import make_reader

    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        w.write_message("a/tick", tick(0), log_time_nanos=0)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (schema,) = summary.schemas.values()
    (channel,) = summary.channels.values()
    body = json.loads(schema.data)
    assert body["type"] == "Tick" and body["packing"] == PACKING
    assert body["description"] == Tick.schema().description
    assert channel.metadata["fingerprint"] == Tick.schema().fingerprint


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("fuzz") / "a.mcap"
    with BagWriter(path, compression="zstd") as w:
        w.add_run_info(graph_text="nodes: {}\n", command_line="x")
        for i in range(12):
            w.write_message("a/tick", tick(i), log_time_nanos=i)
            w.write_message("c/image", tof(i), log_time_nanos=i)
            if i % 4 == 3:
                w.flush()
    return path.read_bytes()


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_damaged_bags_never_raise_anything_but_bag_error(
    small_bag: bytes, data: st.DataObject, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Random flips, cuts and overwrites: the reader warns or raises BagError, nothing else."""
    damaged = bytearray(small_bag)
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(damaged) - 1))
        damaged[at] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        damaged = damaged[: data.draw(st.integers(0, len(damaged)))]
    path = tmp_path_factory.mktemp("damaged") / "d.mcap"
    path.write_bytes(bytes(damaged))
    try:
        with BagReader(path, warn=lambda _: None) as r:
            r.topics()
            r.run_info()
            r.drops()
            for m in r.messages():
                try:
                    m.decode_plain()
                except BagError:
                    pass
            r.stats()
    except BagError:
        pass


def test_chunks_without_wanted_topics_are_not_read(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with BagWriter(path) as w:
        for i in range(3):
            w.write_message("a/tick", tick(i), log_time_nanos=i)
        w.flush()
        for i in range(3):
            w.write_message("b/tick", tick(i), log_time_nanos=10 + i)
        w.flush()
    with BagReader(path) as r:
        second = r.chunks[1]
    _flip(path, second.offset + second.length - 5)  # b/tick's chunk is broken
    problems: list[str] = []
    with BagReader(path, warn=problems.append) as r:
        assert [m.sequence for m in r.messages(["a/tick"])] == [0, 1, 2]
        assert problems == []  # never opened
        assert list(r.messages(["b/tick"])) == [] and len(problems) == 1
