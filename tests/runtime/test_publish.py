"""A node's publish path in a live graph (``ZmqIO.publish``, in this process, no child):
each output's lookups are prepared once, yet every message is still checked against the
output's declared type, numbered, sent as the codec's frames and asked the finite
question of its own class (a subclass's extra finite fields included); only a message
with a field to name is counted as non-finite."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import pytest
import zmq

from messages import GripperState, Header, Pressure, decode
from messages.base import Message
from runtime.zmqio import ZmqIO


class LoudPressure(Pressure):
    """A subclass with one more finite field: published on an output declared Pressure."""

    gain: float = 1.0

    finite_fields: ClassVar[tuple[str, ...]] = ("pressure_pa", "gain")


del Message.registry["LoudPressure"]  # a throwaway: tests that walk the registry never meet it


@pytest.fixture
def io(tmp_path: Path) -> Iterator[tuple[ZmqIO, zmq.Socket[Any]]]:
    ctx: zmq.Context[Any] = zmq.Context()
    spec = {
        "name": "probe",
        "outputs": {"pressure": "probe/pressure", "state": "probe/state"},
        "bind": f"ipc://{tmp_path}/probe",
        "control": f"ipc://{tmp_path}/control",  # nobody listens
        "secret": "00" * 32,
    }
    node_io = ZmqIO(spec, ctx)
    node_io.output_types = {"pressure": Pressure, "state": GripperState}
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(node_io.endpoint)
    sub.setsockopt(zmq.SUBSCRIBE, b"probe/")
    # A SUB joins late: wait until the XPUB has its subscription (verbose, so it is told).
    assert node_io.pub.poll(10_000), "the subscription never arrived"
    node_io.pub.recv()
    yield node_io, sub
    sub.close(linger=0)
    node_io.pub.close(linger=0)
    node_io.control.close(linger=0)
    ctx.term()


def _received(sub: zmq.Socket[Any], n: int) -> list[tuple[str, Message]]:
    out = []
    for _ in range(n):
        assert sub.poll(10_000), "a published message did not arrive"
        out.append(decode(sub.recv_multipart()))
    return out


def _pressure(value: float) -> Pressure:
    return Pressure(header=Header(stamp_nanos=7), sensor="left", pressure_pa=value)


def test_each_message_is_numbered_sent_and_checked_on_its_output(
    io: tuple[ZmqIO, zmq.Socket[Any]],
) -> None:
    node_io, sub = io
    values = [1.0, math.nan, 2.0, -math.inf, 3.0]
    for value in values:
        node_io.publish("pressure", _pressure(value))
    got = _received(sub, len(values))
    assert [topic for topic, _ in got] == ["probe/pressure"] * len(values)
    assert [msg.header.seq for _, msg in got] == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
    assert [msg.pressure_pa for _, msg in got][::2] == [1.0, 2.0, 3.0]  # type: ignore[attr-defined]
    assert node_io.published == {"probe/pressure": 5}
    assert node_io.nonfinite == {"probe/pressure": 2}


def test_a_subclass_is_checked_by_its_own_finite_fields(
    io: tuple[ZmqIO, zmq.Socket[Any]],
) -> None:
    node_io, sub = io
    node_io.publish("pressure", _pressure(1.0))  # prepares the output with Pressure's check
    loud = LoudPressure(header=Header(), sensor="left", pressure_pa=1.0, gain=math.inf)
    node_io.publish("pressure", loud)
    for _ in range(2):  # sent (a receiver here does not know the throwaway class)
        assert sub.poll(10_000)
        assert sub.recv_multipart()[0] == b"probe/pressure"
    assert node_io.nonfinite == {"probe/pressure": 1}


def test_numbers_whose_sum_overflows_are_sent_and_not_counted(
    io: tuple[ZmqIO, zmq.Socket[Any]],
) -> None:
    node_io, sub = io
    big = GripperState(header=Header(), width_m=1e308, speed_m_per_s=1e308, force_n=1e308)
    node_io.publish("state", big)
    [(_, msg)] = _received(sub, 1)
    assert msg == big
    assert not node_io.nonfinite


def test_an_undeclared_output_or_another_type_is_refused_and_nothing_counted(
    io: tuple[ZmqIO, zmq.Socket[Any]],
) -> None:
    node_io, _ = io
    with pytest.raises(KeyError, match="'force' is not a declared output"):
        node_io.publish("force", _pressure(1.0))
    node_io.publish("state", GripperState(header=Header(), width_m=0, speed_m_per_s=0, force_n=0))
    with pytest.raises(TypeError, match=r"probe\.state: expected GripperState, got Pressure"):
        node_io.publish("state", _pressure(1.0))  # the output is prepared by now
    assert node_io.published == {"probe/state": 1}
