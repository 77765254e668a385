"""Bags whose chosen messages cannot be decoded (in intact chunks, so only decoding fails)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import pytest

import runtime.bag.writer as writer_module
from messages.base import Header
from messages.types import Tick
from runtime.bag import BagWriter

MS = 1_000_000


def bag_with_undecodable(path: Path, count: int, bad: dict[int, str]) -> Path:
    """Ticks 0..count-1 on ``a/tick`` (value = index, every 10 ms); message ``i`` in ``bad``
    is stored broken: ``"cut"`` (the MessagePack value cut short) or ``"field"`` (a whole
    value whose ``value`` field is a string, which only a typed decode refuses)."""
    real = writer_module.pack_single
    written = [0]

    def pack(frames: Any) -> bytes:
        data = real(frames)
        kind = bad.get(written[0])
        written[0] += 1
        if kind == "cut":
            return data[:-3]
        if kind == "field":
            value = msgpack.unpackb(data)
            value["fields"]["value"] = "not a number"
            return bytes(msgpack.packb(value))
        return data

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(writer_module, "pack_single", pack)
        with BagWriter(path) as w:
            for i in range(count):
                msg = Tick(header=Header(stamp_nanos=i, seq=i), value=float(i))
                w.write_message("a/tick", msg, log_time_nanos=i * 10 * MS)
    return path
