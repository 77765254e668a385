"""The node runner's multipart send and receive loops against pyzmq's own helpers."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zmq

from bench.codec import LAYOUTS, tof_image
from messages import ToFImage, decode, encode
from runtime.zmqio import recv_parts, send_parts


@pytest.fixture
def pair() -> Iterator[tuple[zmq.Socket[Any], zmq.Socket[Any]]]:
    ctx: zmq.Context[Any] = zmq.Context()
    tx = ctx.socket(zmq.PAIR)
    rx = ctx.socket(zmq.PAIR)
    tx.bind("inproc://parts")
    rx.connect("inproc://parts")
    yield tx, rx
    tx.close(linger=0)
    rx.close(linger=0)
    ctx.term()


def _wait(sock: zmq.Socket[Any]) -> list[zmq.Frame]:
    assert sock.poll(2000), "nothing arrived"
    frames = recv_parts(sock)
    assert frames is not None
    return frames


def test_recv_parts_returns_none_when_nothing_waits(
    pair: tuple[zmq.Socket[Any], zmq.Socket[Any]],
) -> None:
    _, rx = pair
    assert recv_parts(rx) is None


def test_send_parts_and_recv_parts_carry_the_same_frames_as_the_multipart_helpers(
    pair: tuple[zmq.Socket[Any], zmq.Socket[Any]],
) -> None:
    tx, rx = pair
    msg = tof_image(LAYOUTS["ready"])
    frames = encode("left/image", msg)
    send_parts(tx, frames)
    tx.send_multipart(frames, copy=False)
    mine, theirs = _wait(rx), rx.recv_multipart(copy=False)
    assert [f.bytes for f in mine] == [f.bytes for f in theirs]
    _, got = decode(mine, expect=ToFImage)
    assert isinstance(got, ToFImage)
    np.testing.assert_array_equal(got.depth_m, msg.depth_m)
    np.testing.assert_array_equal(got.ir, msg.ir)


def test_recv_parts_keeps_messages_apart(pair: tuple[zmq.Socket[Any], zmq.Socket[Any]]) -> None:
    tx, rx = pair
    send_parts(tx, [b"one"])
    send_parts(tx, [b"two", b"2a", b"2b"])
    send_parts(tx, [b"three", b""])
    got = [[f.bytes for f in _wait(rx)] for _ in range(3)]
    assert got == [[b"one"], [b"two", b"2a", b"2b"], [b"three", b""]]
    assert recv_parts(rx) is None


def test_recv_parts_told_a_message_waits_reads_it_and_never_blocks(
    pair: tuple[zmq.Socket[Any], zmq.Socket[Any]],
) -> None:
    # The runner's first read after a poll skips the EVENTS question (waiting=True): the
    # read is still non-blocking, so a socket with nothing after all answers None.
    tx, rx = pair
    assert recv_parts(rx, waiting=True) is None
    send_parts(tx, [b"topic", b"one", b"two"])
    assert rx.poll(2000)
    frames = recv_parts(rx, waiting=True)
    assert frames is not None and [f.bytes for f in frames] == [b"topic", b"one", b"two"]
    assert recv_parts(rx, waiting=True) is None
