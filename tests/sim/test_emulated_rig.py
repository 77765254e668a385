"""The emulated rig's parts: the as-built rig file, the SDK layout, plugs and faults, the
pressure the emulated bridges read."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from devices.abp import PSI_PA, decode
from geometry.camera import PinholeCamera
from messages.codec import encode
from sim import World, load_scene
from sim import emulated_rig as rig
from sim.wire import to_message

RIG = """
rig: test-rig
cameras:
  left: {camera_id: CAM-L, rpy_deg: [1.0, -1.0, 1.0], xyz_mm: [1.0, 1.0, -1.0], intrinsics: {fx: 190.0}}
pressure:
  right: {serial: BR, offset_pa: 40.0, gain: 1.05}
faults:
  - {device: right_pressure, at_secs: 1.0, for_secs: 0.5}
"""


def test_an_as_built_rig_file_reads_with_defaults_and_checks_its_limits(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text(RIG)
    loaded = rig.load_rig(path)
    left = loaded.cameras["left"]
    assert left.camera_id == "CAM-L" and left.intrinsics == {"fx": 190.0}
    assert np.allclose(left.mount_error[:3, 3], [0.001, 0.001, -0.001])
    assert loaded.cameras["right"] == rig.NOMINAL.cameras["right"]
    assert loaded.pressure["right"] == rig.AsBuiltSensor("BR", 40.0, 1.05, 0.0)
    (fault,) = loaded.faults
    assert fault.active(1.2) and not fault.active(0.9) and not fault.active(1.5)
    path.write_text("cameras: {left: {rpy_deg: [3.0, 3.0, 0.0]}}")
    with pytest.raises(ValueError, match=r"rig.yaml: cameras.left.rpy_deg: more than 3.0 degrees"):
        rig.load_rig(path)
    path.write_text("faults: [{device: left_hand, at_secs: 1}]")
    with pytest.raises(ValueError, match=r"faults\[0\]: `device` must be one of left_camera"):
        rig.load_rig(path)


def test_frames_take_the_sdks_layout_and_confidence() -> None:
    camera = PinholeCamera.from_fov(8, 6)
    depth = np.full(camera.shape, 0.08, np.float32)
    depth[0, 0] = np.nan
    noise = np.full(camera.shape, 0.001, np.float32)
    noise[1, 1] = 0.069
    pts = rig.sdk_points({"depth_m": depth, "noise_m": noise, "amplitude": depth * 1e4}, camera)
    assert pts.shape == (6, 8, 6) and pts.dtype == np.float32
    assert (pts[0, 0] == [0, 0, 0, 0, 0, 0]).all()  # invalid: zeros, confidence 0
    assert np.allclose(pts[2, 3, :3], 0.08 * camera.rays()[2, 3])
    assert pts[2, 3, 5] == pytest.approx(255 * (1 - 0.001 / 0.07)) and pts[1, 1, 5] >= 1


def test_an_emulated_bridge_reads_the_worlds_pressure_as_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "rig.yaml").write_text(RIG)
    (tmp_path / "unplugged").mkdir()
    feed = f"ipc://{tmp_path / 'feed'}"
    session = {
        "feed": feed,
        "rig": str(tmp_path / "rig.yaml"),
        "plugs": str(tmp_path),
        "scene": "scenes/rig_handover.yaml",
    }
    (tmp_path / "session.json").write_text(json.dumps(session))
    monkeypatch.setenv(rig.SESSION_ENV, str(tmp_path / "session.json"))
    rig.forget_session()
    pub = zmq.Context.instance().socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(feed)
    try:
        backend = rig.usb_backend()
        right = backend.bridges[1]
        # Before the world's first state: the bubble's inflation pressure, as built.
        right.answer(bytes([0x91, 2, 0, 0x51]))  # an I2C read of the sensor at 0x28
        reading = decode(right.sensor_bytes, pmin_pa=0, pmax_pa=PSI_PA)
        assert reading.pressure_pa == pytest.approx(1.05 * 1000.0 + 40.0, abs=0.6)
        scene = load_scene("scenes/rig_handover.yaml")
        snap = World(scene).step()
        msg = to_message(snap, scene, 1)
        msg.pressure_pa = [0.0, 500.0]
        msg.time_secs = 1.2  # in the scripted fault's window
        for _ in range(50):  # a late subscriber misses the first messages
            pub.send_multipart(encode("rig/state", msg))
            if rig.feed().poll(timeout_ms=20) is not None:
                break
        assert not rig.session().plugged("right_pressure")
        assert rig.session().plugged("left_pressure") and backend.enumerate_devices() == [0]
        msg.time_secs = 2.0
        pub.send_multipart(encode("rig/state", msg))
        deadline = time.monotonic() + 5
        while rig.feed().poll(timeout_ms=20).time_secs != 2.0 and time.monotonic() < deadline:
            pass
        right.answer(bytes([0x91, 2, 0, 0x51]))
        reading = decode(right.sensor_bytes, pmin_pa=0, pmax_pa=PSI_PA)
        assert reading.pressure_pa == pytest.approx(1.05 * 500.0 + 40.0, abs=0.6)
        (tmp_path / "unplugged" / "left_camera").touch()
        assert not rig.session().plugged("left_camera")
    finally:
        pub.close(0)
        rig.forget_session()
