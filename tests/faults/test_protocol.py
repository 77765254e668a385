"""The control protocol's checks, message by message, and the input counters' arithmetic."""

from __future__ import annotations

import math

import msgpack
import pytest

from messages.control import Connect, Heartbeat, Ready
from runtime import protocol
from runtime.counters import InputCounters
from runtime.protocol import ControlError

SECRET = b"k" * protocol.SECRET_BYTES
STATS = {
    "published": {"a/tick": 3},
    "inputs": {"tick": {"topic": "b/tick", **dict.fromkeys(protocol.INPUT_COUNTERS, 0)}},
    "cpu_secs": 0.5,
}


def test_a_signed_message_round_trips() -> None:
    frames = protocol.pack(SECRET, Heartbeat(node="a", busy_secs=0.25, stats=STATS))
    assert msgpack.unpackb(frames[0]) == {  # a plain MessagePack map, "kind" first
        "kind": "heartbeat",
        "node": "a",
        "busy_secs": 0.25,
        "stats": STATS,
    }
    msg = protocol.unpack(SECRET, frames, from_node=True)
    assert msg == Heartbeat(node="a", busy_secs=0.25, stats=STATS)
    connect = protocol.unpack(SECRET, protocol.pack(SECRET, Connect(endpoints={})), from_node=False)
    assert connect == Connect(endpoints={})


def signed(**body: object) -> list[bytes]:
    payload = msgpack.packb(body, use_bin_type=True)
    return [payload, protocol._tag(SECRET, payload)]


@pytest.mark.parametrize(
    ("frames", "why"),
    [
        ([b"x"], "1 frame"),
        ([b"x", b"y", b"z"], "3 frame"),
        (protocol.pack(b"other secret", Ready(node="a")), "not signed"),
        ([protocol.pack(SECRET, Ready(node="a"))[0], b""], "not signed"),
        (signed(kind="ready", node="a")[:1] + [b"\x00" * 16], "not signed"),
        ([b"\xc1", protocol._tag(SECRET, b"\xc1")], "not MessagePack"),
        ([msgpack.packb([1]), protocol._tag(SECRET, msgpack.packb([1]))], "expected a map"),
        (signed(kind="launch_missiles", node="a"), "unknown kind"),
        (signed(kind=5, node="a"), "unknown kind"),
        (signed(kind="ready"), "ready: Object missing required field `node`"),
        (signed(kind="hello", node="a"), "hello: Object missing required field `endpoint`"),
        (
            signed(kind="hello", node="a", endpoint=5),
            r"hello: .*`str`, got `int` - at `\$\.endpoint`",
        ),
        (
            signed(kind="ready", node="a", colour="red"),
            "ready: Object contains unknown field `colour`",
        ),
        (signed(kind="connect", endpoints={}), "connect: not a message a node sends"),
        (signed(kind="heartbeat", node="a", busy_secs="x", stats={}), r"\$\.busy_secs"),
        (signed(kind="heartbeat", node="a", busy_secs=True, stats={}), r"\$\.busy_secs"),
        (signed(kind="heartbeat", node="a", busy_secs=math.nan, stats={}), r"\$\.busy_secs"),
        (signed(kind="heartbeat", node="a", busy_secs=math.inf, stats={}), r"\$\.busy_secs"),
        (signed(kind="heartbeat", node="a", busy_secs=-1.0, stats={}), r"\$\.busy_secs"),
        (signed(kind="stop_request", node="a", reason="", exit_code=256), r"\$\.exit_code"),
        (signed(kind="heartbeat", node="a", busy_secs=0.0, stats={"published": 3}), "stats"),
        (
            signed(kind="final", node="a", stats={"inputs": {"p": {"topic": "t", "received": -1}}}),
            "stats",
        ),
        (
            signed(kind="counts", node="a", published={"t": "many"}, received={}, held={}),
            "published",
        ),
        (signed(kind="connect", endpoints={"a": 5}), r"\$\.endpoints"),
    ],
)
def test_every_malformed_or_unsigned_message_is_refused(frames: list[bytes], why: str) -> None:
    from_node = frames[0] != signed(kind="connect", endpoints={"a": 5})[0]
    with pytest.raises(ControlError, match=why):
        protocol.unpack(SECRET, frames, from_node=from_node)


def counted(seqs: list[int], bad_after: frozenset[int] = frozenset()) -> InputCounters:
    """Feed ``seqs`` to the counters; a bad frame arrives after each index in ``bad_after``."""
    counters = InputCounters()
    for i, seq in enumerate(seqs):
        counters.note_seq(seq)
        if i in bad_after:
            counters.unseq += 1
    return counters


def test_a_gap_is_dropped_messages() -> None:
    assert counted([0, 1, 2, 5, 6, 7]).dropped == 2
    assert counted([0, 1, 4, 8, 9]).dropped == 2 + 3  # two gaps in a row


def test_a_wild_seq_costs_nothing() -> None:
    assert counted([0, 1, 2, 10**12, 4, 5]).dropped == 0
    assert counted([0, 1, 2, 0, 4, 5]).dropped == 0  # a corrupted 3 that reads as 0
    assert counted([0, 1, 2, 10**12]).dropped == 0  # last, never confirmed


def test_a_restarted_publisher_starts_again_at_zero() -> None:
    assert counted([0, 1, 2, 3, 0, 1, 2]).dropped == 0
    assert counted([5, 6, 7, 0, 1, 3, 4]).dropped == 1


def test_a_bad_frame_is_not_also_dropped() -> None:
    # seq 2 arrived as an undecodable frame: counted as bad by the runner, not dropped here.
    assert counted([0, 1, 3, 4], bad_after=frozenset({1})).dropped == 0
    assert counted([0, 1, 4, 5], bad_after=frozenset({1})).dropped == 1
