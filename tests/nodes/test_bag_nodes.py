"""The recorder and replay nodes with the fake IO (no sockets, a clock that moves when told)."""

from __future__ import annotations

from pathlib import Path

import msgpack
import pytest

from messages.base import Header
from messages.codec import encode, pack_single
from messages.errors import NodeError
from messages.types import Pressure, Tick
from nodes.recorder import Recorder
from nodes.replay import Replay
from runtime.bag import BagReader, BagWriter
from runtime.params import build_params
from runtime.testing import FakeIO, make_node
from tests.runtime.bad_bags import bag_with_undecodable

MS = 1_000_000


def tick(i: int, value: float | None = None) -> Tick:
    return Tick(
        header=Header(stamp_nanos=7_000 + i, seq=i), value=float(i if value is None else value)
    )


@pytest.fixture
def bag(tmp_path: Path) -> Path:
    """Ticks on a/tick every 10 ms (0..9) and pressures on p/pressure every 25 ms (0..3)."""
    path = tmp_path / "in.mcap"
    with BagWriter(path) as w:
        events = [(i * 10 * MS, "a/tick", tick(i)) for i in range(10)]
        events += [
            (
                i * 25 * MS + 1,
                "p/pressure",
                Pressure(header=Header(seq=i), sensor="left", pressure_pa=i),
            )
            for i in range(4)
        ]
        for t, topic, msg in sorted(events, key=lambda e: e[0]):
            w.write_message(topic, msg, log_time_nanos=1_000 * MS + t)
    return path


# -- recorder -----------------------------------------------------------------------------------


def test_recorder_writes_frames_drops_and_run_info(tmp_path: Path) -> None:
    path = tmp_path / "out" / "rec.mcap"
    node, io = make_node(
        Recorder,
        {
            "path": str(path),
            "graph_yaml": "nodes: {src: {impl: synthetic.source}}\n",
            "command_line": "launch.py g.yaml --record rec.mcap",
            "flush_period_secs": 0.1,
        },
        now_nanos=5 * MS,
    )
    for seq in (0, 1, 2, 5):
        node.on_raw("src/tick", encode("src/tick", tick(seq)))
        io.advance(0.01)
    node.on_raw("src/tick", [b"src/tick", b"not msgpack \xc1"])
    io.dropped = {"src/tick": 3}
    io.advance(0.2)  # the flush timer fires: readable even if killed now
    with BagReader(path, warn=lambda _: None) as r:
        assert [m.sequence for m in r.messages()] == [0, 1, 2, 5]
        assert r.drops()["src/tick"] == {"runtime": 3, "seq_gaps": 2, "rejected": 1}
    node.teardown()
    with BagReader(path) as r:
        assert r.has_summary
        msgs = list(r.messages())
        assert [m.log_time_nanos for m in msgs] == [5 * MS + i * 10 * MS for i in range(4)]
        assert [m.decode().value for m in msgs] == [0.0, 1.0, 2.0, 5.0]
        assert r.run_info()["command_line"] == "launch.py g.yaml --record rec.mcap"
        assert "synthetic.source" in r.run_info()["graph_yaml"]


def test_recorder_rejects_bad_params() -> None:
    from nodes.recorder import RecorderParams

    with pytest.raises(ValueError, match="compression"):
        build_params(RecorderParams, {"path": "x.mcap", "compression": "rar"})
    with pytest.raises(ValueError, match="flush_period_secs must be > 0, got 0"):
        build_params(RecorderParams, {"path": "x.mcap", "flush_period_secs": 0})


def make_replay(params: dict) -> tuple[Replay, object]:
    """A replay node whose timer ticks never run out of (real) time on a loaded machine."""
    return make_node(Replay, {"batch_secs": 60.0, **params})


# -- replay ------------------------------------------------------------------------------------


def published(io: object, topic: str) -> list[float]:
    return [getattr(m, "value", getattr(m, "pressure_pa", None)) for m in io.published[topic]]  # type: ignore[attr-defined]


def test_replay_ports_are_the_bag_topics(bag: Path) -> None:
    params = build_params(Replay.Params, {"path": str(bag)})
    inputs, outputs = Replay.ports(params)
    assert inputs == {} and outputs == {"a/tick": Tick, "p/pressure": Pressure}
    params = build_params(
        Replay.Params, {"path": str(bag), "topics": "a/.*", "remap": {"a/tick": "cam/tick"}}
    )
    assert Replay.ports(params)[1] == {"cam/tick": Tick}


def test_replay_paces_by_recorded_time(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "topics": "a/tick"})
    io.advance(0.001)  # first tick: message 0 (the clock starts here)
    assert published(io, "a/tick") == [0.0]
    io.advance(0.0305)
    assert published(io, "a/tick") == [0.0, 1.0, 2.0, 3.0]
    io.advance(1.0)
    assert published(io, "a/tick") == [float(i) for i in range(10)]
    assert io.stop_reason is not None and "replayed 10 messages" in io.stop_reason


def test_replay_rate_factor(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "topics": "a/tick", "rate": 2.0})
    io.advance(0.001)
    io.advance(0.0305)  # 30 ms of wall time = 60 ms of bag time
    assert published(io, "a/tick") == [float(i) for i in range(7)]


def test_replay_fast_publishes_everything_at_once_in_file_order(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "fast": True})
    io.advance(0.001)
    assert published(io, "a/tick") == [float(i) for i in range(10)]
    assert published(io, "p/pressure") == [0.0, 1.0, 2.0, 3.0]
    assert io.stop_reason is not None


def test_replay_counts_the_non_finite_messages_it_publishes(tmp_path: Path) -> None:
    # The replay is where a replayed message is published: a bag of broken pressures
    # is counted there (the subscribers do not check again).
    path = tmp_path / "nan.mcap"
    with BagWriter(path) as w:
        for i, value in enumerate((1200.0, float("nan"), 1300.0, float("inf"))):
            msg = Pressure(header=Header(seq=i), sensor="left", pressure_pa=value)
            w.write_message("p/pressure", msg, log_time_nanos=1_000 * MS + i * MS)
    node, io = make_replay({"path": str(path), "fast": True})
    io.advance(0.001)
    assert len(io.published["p/pressure"]) == 4
    assert io.nonfinite == {"p/pressure": 2}


def test_replay_keeps_recorded_seq_and_stamps(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "fast": True, "topics": "a/tick"})
    io.advance(0.001)
    msgs = io.published["a/tick"]
    assert [m.header.seq for m in msgs] == list(range(10))
    assert [m.header.stamp_nanos for m in msgs] == [7_000 + i for i in range(10)]


def test_replay_start_end_window(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "fast": True, "start_secs": 0.02, "end_secs": 0.05})
    io.advance(0.001)
    assert published(io, "a/tick") == [2.0, 3.0, 4.0]
    assert published(io, "p/pressure") == [1.0]


def test_replay_topic_selection_and_remap(bag: Path) -> None:
    node, io = make_replay(
        {"path": str(bag), "fast": True, "topics": "p/.*", "remap": {"p/pressure": "left/p"}},
    )
    io.advance(0.001)
    assert set(io.published) == {"left/p"}
    assert published(io, "left/p") == [0.0, 1.0, 2.0, 3.0]


def test_replay_loop(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "topics": "a/tick", "loop": True, "rate": 10.0})
    io.advance(0.001)
    io.advance(0.025)  # one pass takes 9 ms at rate 10; a few passes fit
    values = published(io, "a/tick")
    assert len(values) > 20 and values[:20] == [float(i % 10) for i in range(20)]
    assert io.stop_reason is None


def record_idle_waits(io: FakeIO) -> list[int]:
    """Make ``io.wait_idle`` record how many messages were published when it was called."""
    calls: list[int] = []

    def wait_idle(timeout_secs: float, *, last: bool = False) -> bool:
        calls.append(sum(len(v) for v in io.published.values()))
        return True

    io.wait_idle = wait_idle  # type: ignore[method-assign]
    return calls


def test_replay_lockstep_waits_for_idle_before_each_message(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "lockstep": True})
    calls = record_idle_waits(io)
    io.advance(0.001)
    # Every topic a barrier (FakeIO's answer): one wait before each of the 14 messages,
    # with everything before it published, and one more before asking the graph to stop.
    assert calls == [*range(14), 14]
    assert io.stop_reason is not None


def test_replay_lockstep_pipelines_topics_without_a_barrier(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "lockstep": True, "window": 4})
    io.lockstep_barrier = lambda topic: topic == "p/pressure"  # type: ignore[method-assign]
    calls = record_idle_waits(io)
    io.advance(0.001)
    with BagReader(bag) as reader:
        order = [m.topic for m in reader.messages()]
    # A wait before each pressure (4 of them), and after 4 ticks in flight without one.
    expected, in_flight = [], 0
    for sent, topic in enumerate(order):
        if topic == "p/pressure" or in_flight >= 4:
            expected.append(sent)
            in_flight = 0
        in_flight += 1
    assert calls == [*expected, 14] and 4 <= len(expected) < 14


def test_replay_lockstep_timeout_is_an_error(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "lockstep": True, "idle_timeout_secs": 0.5})
    io.wait_idle = lambda timeout_secs: False  # type: ignore[method-assign]
    with pytest.raises(NodeError, match=r"graph not idle after 0\.5 s before message 0"):
        io.advance(0.001)


def test_replay_refuses_a_schema_the_graph_cannot_accept(tmp_path: Path) -> None:
    path = tmp_path / "changed.mcap"
    frames = encode("a/tick", tick(0))
    head = msgpack.unpackb(bytes(frames[1]))
    head["fp"] = "0000000000000000"  # recorded when Tick had other fields
    with BagWriter(path) as w:
        w.write_frames("a/tick", [frames[0], msgpack.packb(head), *frames[2:]], log_time_nanos=1)
    with BagReader(path) as r:
        offset = r.channels[1].offset
        assert offset > 0
        assert r.topics()["a/tick"].description is None  # not today's Tick: no description
    with pytest.raises(
        ValueError, match=rf"changed\.mcap: topic a/tick: channel at offset {offset}"
    ):
        make_replay({"path": str(path)})


def test_replay_bad_params(bag: Path) -> None:
    with pytest.raises(ValueError, match="rate must be > 0"):
        build_params(Replay.Params, {"path": str(bag), "rate": 0})
    with pytest.raises(ValueError, match="end_secs must be > start_secs"):
        build_params(Replay.Params, {"path": str(bag), "start_secs": 2, "end_secs": 1})
    with pytest.raises(ValueError, match="bad regular expression"):
        build_params(Replay.Params, {"path": str(bag), "topics": "("})
    params = build_params(Replay.Params, {"path": str(bag), "topics": "nothing/.*"})
    with pytest.raises(ValueError, match="selects none"):
        Replay.ports(params)
    params = build_params(Replay.Params, {"path": str(bag), "remap": {"x/y": "a/b"}})
    with pytest.raises(ValueError, match="remap names topics not in the bag"):
        Replay.ports(params)


def test_replay_publishes_the_recorded_frames_byte_for_byte(bag: Path) -> None:
    """The bag holds one MessagePack value; unpacked, it is the wire frames as recorded."""
    with BagReader(bag) as r:
        m = next(iter(r.messages(["a/tick"])))
        assert bytes(m.payload) == pack_single(encode("a/tick", tick(0))[1:])
        wire = [bytes(memoryview(f).cast("B")) for f in encode("a/tick", tick(0))]
        assert [bytes(f) for f in m.wire_frames()] == wire


def test_replay_fast_bounds_messages_in_flight(bag: Path) -> None:
    node, io = make_replay({"path": str(bag), "fast": True, "window": 4})
    calls = record_idle_waits(io)
    io.advance(0.001)
    assert calls == [4, 8, 12, 14]  # every 4 messages, and once more before stopping


def test_restarted_recorder_keeps_the_interrupted_bag(tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    with BagWriter(path) as w:
        w.write_message("a/tick", tick(0), log_time_nanos=0)
    complete = path.read_bytes()
    path.write_bytes(complete[:-30])  # the first incarnation was killed
    node, io = make_node(Recorder, {"path": str(path)})
    node.on_raw("a/tick", encode("a/tick", tick(1)))
    node.teardown()
    assert path.read_bytes() == complete[:-30]
    with BagReader(tmp_path / "rec.1.mcap") as r:
        assert [m.sequence for m in r.messages()] == [1]
    finished = (tmp_path / "rec.1.mcap").read_bytes()
    with pytest.raises(ValueError, match=r"rec\.1\.mcap' is a finished bag; pass --overwrite"):
        make_node(Recorder, {"path": str(tmp_path / "rec.1.mcap")})
    assert (tmp_path / "rec.1.mcap").read_bytes() == finished
    assert not (tmp_path / "rec.1.1.mcap").exists() and not (tmp_path / "rec.2.mcap").exists()


def test_replay_skips_and_counts_messages_it_cannot_decode(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = bag_with_undecodable(tmp_path / "bad.mcap", 8, {2: "cut", 5: "field"})
    node, io = make_replay({"path": str(path), "fast": True})
    io.advance(0.001)
    assert published(io, "a/tick") == [0.0, 1.0, 3.0, 4.0, 6.0, 7.0]
    assert node.skipped == 2
    assert io.stop_reason is not None
    assert "replayed 6 messages" in io.stop_reason and "2 skipped" in io.stop_reason
    assert "bad.mcap: topic a/tick: message at offset" in caplog.text


def test_replay_strict_stops_at_the_first_message_it_cannot_decode(tmp_path: Path) -> None:
    path = bag_with_undecodable(tmp_path / "bad.mcap", 8, {5: "field"})
    node, io = make_replay({"path": str(path), "fast": True, "strict": True})
    with pytest.raises(NodeError, match=r"cannot decode \(strict\): .*bad\.mcap: topic a/tick"):
        io.advance(0.001)
    assert published(io, "a/tick") == [0.0, 1.0, 2.0, 3.0, 4.0]
