"""No display, no viewer: one clear line, a non-zero exit, nothing left running; and a
viewer stream that takes nothing does not hold the process past Ctrl-C or SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from messages.base import Header
from messages.types import ToFImage
from runtime.bag import BagWriter
from viz.display import has_display

ROOT = Path(__file__).resolve().parents[2]
DISPLAY_VARS = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")


def headless_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in DISPLAY_VARS}
    env["PYTHONPATH"] = str(ROOT)
    return env


def small_bag(path: Path) -> Path:
    depth = np.full((4, 6), 0.05, np.float32)
    ir = np.zeros((4, 6), np.uint16)
    with BagWriter(path) as writer:
        for i in range(3):
            image = ToFImage(
                header=Header(stamp_nanos=(i + 1) * 33_000_000, frame_id="left_sensor"),
                sensor="left",
                depth_m=depth,
                ir=ir,
                fx_px=5.0,
                fy_px=5.0,
                cx_px=3.0,
                cy_px=2.0,
            )
            writer.write_message("left_camera/image", image, (i + 1) * 33_000_000)
    return path


def run_alone(cmd: list[str], timeout: float) -> subprocess.CompletedProcess[str]:
    """Run ``cmd`` in a session of its own; fail if anything of that session outlives it."""
    proc = subprocess.Popen(
        cmd,
        cwd=ROOT,
        env=headless_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        left = _session_alive(proc.pid)
        if proc.poll() is None or left:
            os.killpg(proc.pid, signal.SIGKILL)
    assert not left, f"{cmd}: processes left running after it exited"
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _session_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def test_has_display_reads_the_environment() -> None:
    if sys.platform in ("darwin", "win32"):
        pytest.skip("a display is always there on macOS and Windows")
    assert not has_display({})
    assert has_display({"DISPLAY": ":0"})
    assert has_display({"WAYLAND_DISPLAY": "wayland-0"})


@pytest.mark.skipif(sys.platform == "darwin", reason="macOS always has a display")
def test_bag_view_without_a_display_says_so_and_exits(tmp_path: Path) -> None:
    bag = small_bag(tmp_path / "run.mcap")
    proc = run_alone([sys.executable, "launch.py", "bag", "view", str(bag)], 60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "no display" in lines[0] and "--out FILE.rrd" in lines[0] and "foxglove" in lines[0]


@pytest.mark.skipif(sys.platform == "darwin", reason="macOS always has a display")
def test_view_option_without_a_display_starts_nothing() -> None:
    proc = run_alone([sys.executable, "launch.py", "graph.yaml", "--view"], 60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "no display" in lines[0] and "--view FILE.rrd" in lines[0]
    assert "--view foxglove" in lines[0]


FLUSH_INTO_NOTHING = """
import signal, sys
import rerun as rr
import launch  # its Ctrl-C and SIGTERM handlers
signal.signal(signal.SIGINT, launch._interrupted)
signal.signal(signal.SIGTERM, launch._interrupted)
from cli.bagview import ends_at_once_when_interrupted
from viz.rerun_log import flush
rec = rr.RecordingStream("t")
rec.connect_grpc("rerun+http://127.0.0.1:9/proxy")  # nothing listens there
for i in range(100):
    rec.log("x", rr.Scalars([float(i)]))
with ends_at_once_when_interrupted():
    print("flushing", flush=True)
    flush(rec)
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_flush_into_a_gone_viewer_ends_on_a_signal(signum: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", FLUSH_INTO_NOTHING],
        cwd=ROOT,
        env=headless_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "flushing"
        # Most likely inside the flush by now (a signal just before it ends the run the
        # same way): a flush that did not hear it would wait for good, past the bound.
        time.sleep(0.5)
        assert proc.poll() is None
        proc.send_signal(signum)
        code = proc.wait(timeout=30)
        assert code == 128 + signum
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.skipif(
    sys.platform != "linux" or Path("/tmp/.X11-unix/X99").exists(),
    reason="needs Linux and no X server on display :99",
)
def test_bag_view_whose_viewer_cannot_open_says_so_and_exits(tmp_path: Path) -> None:
    """A display that is named but cannot be opened: the viewer exits, and bag view says
    so with the viewer's own last line instead of waiting for it for good."""
    bag = small_bag(tmp_path / "run.mcap")
    env = dict(headless_env(), DISPLAY=":99")
    proc = subprocess.run(
        [sys.executable, "launch.py", "bag", "view", str(bag)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "the Rerun viewer exited (code" in proc.stderr
