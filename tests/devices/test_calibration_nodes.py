"""The hardware graph's device nodes read a rig's calibration file, made for their devices."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from devices import mcp2221
from devices.abp import PSI_PA
from geometry.gripper import GripperGeometry, tool_from_sensor
from geometry.se3 import make_pose, rotation_about
from messages.base import Header
from messages.errors import NodeError
from messages.types import GripperState
from nodes.bubble_camera import RoyaleBubbleCamera
from nodes.pressure import UsbPressure
from perception.calibration.rigfile import (
    CameraCalibration,
    PressureCalibration,
    RigCalibration,
    load_calibration,
)
from runtime.params import ParamError
from runtime.testing import feed, make_node
from sim.mcp2221_emulator import EmulatedBackend, EmulatedBridge, abp_bytes
from sim.royale_sdk import roypy as fake_roypy

CAD = GripperGeometry().finger_from_sensor()
OFF = make_pose(rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(2.0)), [0.002, 0.0, 0.001])


@pytest.fixture
def calibration(tmp_path: Path) -> Path:
    path = tmp_path / "lab.yaml"
    RigCalibration(
        rig="lab-1",
        date="2026-11-26T10:00:00+00:00",
        cameras={"left": CameraCalibration("CAM-L", CAD @ OFF, 0.05, 0.04)},
        pressure={"left": PressureCalibration("BUBBLE-L", 40.0, 0.06, 0.8)},
    ).save(path)
    return path


def test_the_file_reads_back_as_written(calibration: Path) -> None:
    cal = load_calibration(calibration)
    assert cal.rig == "lab-1" and cal.date.startswith("2026-11-26")
    assert np.allclose(cal.cameras["left"].finger_from_sensor, CAD @ OFF, atol=1e-8)
    assert cal.pressure["left"] == PressureCalibration("BUBBLE-L", 40.0, 0.06, 0.8)


def test_a_bad_file_is_refused_naming_the_file_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "rig: x\ndate: y\npressure: {left: {serial: S, offset_pa: nope, offset_sigma_pa: 1}}\n"
    )
    with pytest.raises(ValueError, match=r"bad.yaml: pressure.left.offset_pa: must be a finite"):
        load_calibration(bad)
    bad.write_text(
        "rig: x\ndate: y\ncameras: {left: {camera_id: C, finger_from_sensor: [[1, 0], [0, 1]]}}\n"
    )
    with pytest.raises(
        ValueError, match=r"cameras.left: `finger_from_sensor` must be a finite 4x4"
    ):
        load_calibration(bad)
    with pytest.raises(ParamError, match="calibration"):
        make_node(RoyaleBubbleCamera, {"sensor": "left", "calibration": str(bad)})


def _camera(monkeypatch: pytest.MonkeyPatch, camera_id: str, calibration: Path):  # noqa: ANN202
    roypy = fake_roypy.module(camera_id)
    monkeypatch.setitem(sys.modules, "roypy", roypy)
    params = {"sensor": "left", "calibration": str(calibration)}
    return (*make_node(RoyaleBubbleCamera, params, name="left_camera"), roypy.cameras[camera_id])


def test_a_calibrated_camera_places_frames_with_its_measured_mount(
    monkeypatch: pytest.MonkeyPatch, calibration: Path
) -> None:
    node, io, camera = _camera(monkeypatch, "CAM-L", calibration)
    points = np.zeros((4, 5, 6))
    points[..., 2], points[..., 5] = 0.08, 255
    camera.emit(points, stamp_us=1000)
    state = GripperState(
        header=Header(stamp_nanos=2_000_000), width_m=0.08, speed_m_per_s=0.0, force_n=0.0
    )
    feed(node, "gripper", state)
    node.tick()
    (image,) = io.published["image"]
    finger = GripperGeometry().tool_from_finger("left", 0.08)
    assert np.allclose(image.tool_from_sensor, finger @ CAD @ OFF)
    assert not np.allclose(image.tool_from_sensor, tool_from_sensor("left", 0.08), atol=1e-4)


def test_a_calibration_made_for_another_camera_is_refused(
    monkeypatch: pytest.MonkeyPatch, calibration: Path
) -> None:
    with pytest.raises(
        NodeError,
        match=r"left_camera: calibration refused: .*lab.yaml: made for left camera 'CAM-L'"
        r" \(rig 'lab-1', 2026-11-26.*\), but camera 'CAM-X' is plugged in",
    ):
        _camera(monkeypatch, "CAM-X", calibration)


def _bus(monkeypatch: pytest.MonkeyPatch, serial: str) -> None:
    bridge = EmulatedBridge(serial, sensor_bytes=abp_bytes(1040.0, pmin_pa=0.0, pmax_pa=PSI_PA))
    monkeypatch.setattr(mcp2221, "default_backend", lambda: EmulatedBackend(bridge))


def test_a_calibrated_pressure_sensor_reads_from_its_zero(
    monkeypatch: pytest.MonkeyPatch, calibration: Path
) -> None:
    _bus(monkeypatch, "BUBBLE-L")
    node, io = make_node(UsbPressure, {"sensor": "left", "calibration": str(calibration)})
    node.tick()
    (msg,) = io.published["pressure"]
    assert msg.pressure_pa == pytest.approx(1000.0, abs=0.6)  # one count: 0.53 Pa


def test_a_calibration_made_for_another_bridge_is_refused(
    monkeypatch: pytest.MonkeyPatch, calibration: Path
) -> None:
    _bus(monkeypatch, "BUBBLE-X")
    with pytest.raises(
        NodeError,
        match=r"calibration refused: .*made for left pressure bridge 'BUBBLE-L'.*'BUBBLE-X' is plugged in",
    ):
        make_node(UsbPressure, {"sensor": "left", "calibration": str(calibration)}, name="left")


@pytest.mark.parametrize("wheel", ["not installed", "its library does not load"])
def test_without_a_libusb_backend_the_pressure_node_says_so_in_one_line(
    monkeypatch: pytest.MonkeyPatch, wheel: str
) -> None:
    import types

    import usb.backend.libusb1

    monkeypatch.delenv(mcp2221.BACKEND_ENV, raising=False)
    if wheel == "not installed":
        monkeypatch.setitem(sys.modules, "libusb_package", None)  # import fails
    else:
        stub = types.ModuleType("libusb_package")
        stub.get_libusb1_backend = lambda: None  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, "libusb_package", stub)
    monkeypatch.setattr(usb.backend.libusb1, "get_backend", lambda: None)
    with pytest.raises(NodeError) as err:
        make_node(UsbPressure, {"sensor": "left"}, name="left_pressure")
    text = str(err.value)
    assert text.startswith("left_pressure: pyusb has no libusb-1.0 backend") and "\n" not in text
    assert "neither did the system's libusb-1.0" in text
