"""Recording under faults: a full disk, a directory at the path, a finished bag in the way.

A full disk is a real one where the tests run as root (a 256 KiB tmpfs), and otherwise a
file object whose writes fail with ENOSPC; both must leave a bag readable up to the last
flush and one clear line.
"""

from __future__ import annotations

import errno
import io
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import nodes.recorder  # noqa: F401  (registers the implementations the graphs name)
from messages.base import Header
from messages.codec import encode
from messages.errors import BagError, NodeError
from messages.types import Tick
from nodes.recorder import Recorder
from runtime.bag import BagReader, BagWriter
from runtime.params import build_params
from runtime.testing import make_node
from tests.runtime.conftest import GraphRun


def tick(i: int, payload_bytes: int = 2000) -> Tick:
    payload = np.full(payload_bytes, i % 251, np.uint8)
    return Tick(header=Header(stamp_nanos=i, seq=i), value=float(i), payload=payload)


@pytest.fixture
def tiny_disk(tmp_path: Path) -> Iterator[Path]:
    """A 256 KiB tmpfs (root only; skipped elsewhere, the patched-file test still runs)."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root; the ENOSPC file-object test covers it")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(writer: BagWriter, count: int = 10_000) -> tuple[int, BagError]:
    """Write ticks (flushing every 10) until the writer fails; the index and the error."""
    for i in range(count):
        try:
            writer.write_message("a/tick", tick(i), log_time_nanos=i)
            if i % 10 == 9:
                writer.flush()
        except BagError as err:
            return i, err
    raise AssertionError("the disk never filled")


def check_readable_prefix(path: Path, flushed: int) -> None:
    """The bag reads, in order, at least everything flushed before the failure."""
    with BagReader(path, warn=lambda _: None) as r:
        values = [m.decode().value for m in r.messages()]  # type: ignore[attr-defined]
    assert values == [float(i) for i in range(len(values))]
    assert len(values) >= flushed > 0


def test_full_disk_is_one_clear_error_and_the_bag_stays_readable(tiny_disk: Path) -> None:
    path = tiny_disk / "full.mcap"
    writer = BagWriter(path)
    failed_at, err = fill(writer)
    text = str(err)
    assert str(path) in text and "the disk is full" in text and "\n" not in text
    assert f"keeps the {writer.flushed_messages} message(s) written before the last flush" in text
    with pytest.raises(BagError, match="the disk is full"):  # nothing more is written
        writer.write_message("a/tick", tick(failed_at), log_time_nanos=0)
    writer.close()  # no second error, no summary attempted
    check_readable_prefix(path, writer.flushed_messages)


class FailingFile(io.BufferedWriter):
    """A file whose writes fail with ENOSPC once ``budget`` bytes have been written."""

    def __init__(self, path: Path, budget: int) -> None:
        super().__init__(io.FileIO(path, "w"))
        self.budget = budget

    def write(self, data: Any) -> int:
        size = memoryview(data).nbytes
        if size > self.budget:
            written = super().write(memoryview(data)[: self.budget])
            self.budget = 0
            super().flush()
            raise OSError(errno.ENOSPC, f"No space left on device (after {written} bytes)")
        self.budget -= size
        return super().write(data)


def test_failed_write_by_a_patched_file_object(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same as a real full disk, without root: the file object's write fails."""
    path = tmp_path / "full.mcap"
    import runtime.bag.writer as writer_module

    monkeypatch.setattr(writer_module, "open", lambda p, mode: FailingFile(Path(p), 60_000), False)
    writer = BagWriter(path)
    _, err = fill(writer)
    assert "the disk is full" in str(err)
    writer.close()
    check_readable_prefix(path, writer.flushed_messages)


def test_recorder_node_on_a_full_disk_raises_one_line(tiny_disk: Path) -> None:
    node, io_ = make_node(
        Recorder, {"path": str(tiny_disk / "rec.mcap"), "flush_period_secs": 0.01}
    )
    with pytest.raises(NodeError) as caught:
        for i in range(10_000):
            node.on_raw("a/tick", encode("a/tick", tick(i)))
            io_.advance(0.02)  # the flush timer
    assert str(caught.value).startswith("test: ") and "the disk is full" in str(caught.value)
    node.teardown()  # closes what it can, quietly
    check_readable_prefix(tiny_disk / "rec.mcap", 1)


def test_recorder_refuses_a_directory_and_a_finished_bag(tmp_path: Path) -> None:
    from nodes.recorder import RecorderParams

    with pytest.raises(ValueError, match=rf"path '{tmp_path}' is a directory"):
        build_params(RecorderParams, {"path": str(tmp_path)})
    done = tmp_path / "done.mcap"
    with BagWriter(done) as w:
        w.write_message("a/tick", tick(0), log_time_nanos=0)
    before = done.read_bytes()
    with pytest.raises(ValueError, match=r"done\.mcap' is a finished bag; pass --overwrite"):
        build_params(RecorderParams, {"path": str(done)})
    node, _ = make_node(Recorder, {"path": str(done), "overwrite": True})
    node.on_raw("a/tick", encode("a/tick", tick(7)))
    node.teardown()
    assert done.read_bytes() != before
    with BagReader(done) as r:
        assert [m.sequence for m in r.messages()] == [7]


SOURCE = {"src": {"impl": "synthetic.source", "params": {"rate_hz": 200, "count": 20}}}


def test_cli_refuses_a_finished_bag_unless_overwrite(graph_run: GraphRun, tmp_path: Path) -> None:
    graph = graph_run.write(SOURCE)
    out = tmp_path / "run.mcap"
    code, text = graph_run.run(graph, "--record", str(out), "--log-level", "WARNING")
    assert code == 0, text
    first = out.read_bytes()
    code, text = graph_run.run(graph, "--record", str(out))
    assert code == 2 and f"path '{out}' is a finished bag; pass --overwrite" in text
    assert "Traceback" not in text and out.read_bytes() == first
    code, text = graph_run.run(graph, "--record", str(tmp_path), "--log-level", "WARNING")
    assert code == 2 and "is a directory" in text and "Traceback" not in text
    code, text = graph_run.run(graph, "--record", str(out), "--overwrite", "--log-level", "WARNING")
    assert code == 0, text
    with BagReader(out) as r:
        assert len(list(r.messages())) == 20


def test_cli_full_disk_is_one_line_not_a_traceback(graph_run: GraphRun, tiny_disk: Path) -> None:
    # 200 kB/s: a flush or two (every 0.5 s) reach the disk before it fills.
    params = {"rate_hz": 100, "count": 1000, "payload_bytes": 2000}
    graph = graph_run.write({"src": {"impl": "synthetic.source", "params": params}})
    out = tiny_disk / "run.mcap"
    code, text = graph_run.run(graph, "--record", str(out), "--log-level", "WARNING")
    assert code != 0, text
    assert "Traceback" not in text, text
    errors = [line for line in text.splitlines() if "the disk is full" in line]
    assert len(errors) == 1, text  # said once: the launcher does not echo it again
    assert str(out) in errors[0]
    with BagReader(out, warn=lambda _: None) as r:
        assert len(list(r.messages())) > 0
