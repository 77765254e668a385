"""``pressure.usb`` through its real pyusb code, against bridges emulated at the USB level."""

from __future__ import annotations

import logging
import time
from typing import Any

import pytest

from devices import mcp2221
from devices.abp import COUNTS_MAX, COUNTS_MIN, PSI_PA, AbpStatus, decode
from messages.errors import NodeError
from nodes.pressure import UsbPressure
from runtime.testing import FakeIO, make_node
from sim.mcp2221_emulator import EmulatedBackend, EmulatedBridge, abp_bytes


def _counts(counts: int, status: int = 0) -> bytes:
    return bytes([(status << 6) | (counts >> 8), counts & 0xFF])


@pytest.fixture
def bus(monkeypatch: pytest.MonkeyPatch) -> EmulatedBackend:
    """Two bridges, one per bubble, on an emulated USB bus the node finds by default."""
    backend = EmulatedBackend(
        EmulatedBridge("BUBBLE-L", sensor_bytes=abp_bytes(900.0, pmin_pa=0.0, pmax_pa=PSI_PA)),
        EmulatedBridge("BUBBLE-R", sensor_bytes=abp_bytes(1250.0, pmin_pa=0.0, pmax_pa=PSI_PA)),
    )
    monkeypatch.setattr(mcp2221, "default_backend", lambda: backend)
    return backend


def _node(sensor: str, serial: str, **params: Any) -> tuple[UsbPressure, FakeIO]:
    return make_node(UsbPressure, {"sensor": sensor, "serial": serial, **params}, name=sensor)


def _tick(node: UsbPressure, io: FakeIO, n: int = 1) -> list[float]:
    for _ in range(n):
        node.tick()
    return [m.pressure_pa for m in io.published["pressure"]]


def test_two_bridges_are_told_apart_by_serial(bus: EmulatedBackend) -> None:
    left, left_io = _node("left", "BUBBLE-L")
    right, right_io = _node("right", "BUBBLE-R")
    assert _tick(left, left_io) == [pytest.approx(900.0, abs=0.6)]  # one count: 0.53 Pa
    assert _tick(right, right_io) == [pytest.approx(1250.0, abs=0.6)]
    msg = right_io.published["pressure"][0]
    assert msg.sensor == "right" and msg.header.frame_id == "right_bubble"
    # The kernel's HID driver was detached from both, the I2C clock set to 100 kHz.
    assert [b.kernel_driver for b in bus.bridges] == [False, False]
    assert [b.speed_divider for b in bus.bridges] == [117, 117]


@pytest.mark.parametrize(
    ("counts", "expected_pa"),
    [(COUNTS_MIN, 0.0), (COUNTS_MAX, PSI_PA), ((COUNTS_MIN + COUNTS_MAX) // 2, 3447.1155)],
)
def test_readings_at_both_ends_and_in_the_middle(
    bus: EmulatedBackend, counts: int, expected_pa: float
) -> None:
    bus.bridges[0].sensor_bytes = _counts(counts)
    node, io = _node("left", "BUBBLE-L")
    assert _tick(node, io) == [pytest.approx(expected_pa, abs=1e-3)]


def test_a_gauge_range_that_starts_below_zero() -> None:
    reading = decode(_counts(COUNTS_MIN), pmin_pa=-1000.0, pmax_pa=1000.0)
    assert reading.pressure_pa == pytest.approx(-1000.0)
    assert decode(_counts(COUNTS_MAX), pmin_pa=-1000.0, pmax_pa=1000.0).pressure_pa == 1000.0


def test_a_diagnostic_fault_is_reported_and_the_bridge_reset(
    bus: EmulatedBackend, caplog: pytest.LogCaptureFixture
) -> None:
    node, io = _node("left", "BUBBLE-L", retry_secs=0.01)
    bus.bridges[0].sensor_bytes = _counts(5000, status=AbpStatus.FAULT)
    assert _tick(node, io, 3) == []
    assert "reports a diagnostic fault (status bits 11" in caplog.text
    assert "resetting MCP2221A 'BUBBLE-L'" in caplog.text
    assert bus.bridges[0].kernel_driver  # re-enumerated: the kernel took it again
    bus.bridges[0].sensor_bytes = abp_bytes(500.0, pmin_pa=0.0, pmax_pa=PSI_PA)
    time.sleep(0.02)
    assert _tick(node, io) == [pytest.approx(500.0, abs=0.6)]  # reconnects, reads


def test_stale_readings_are_skipped_and_saturated_ones_flagged(
    bus: EmulatedBackend, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    node, io = _node("left", "BUBBLE-L")
    bus.bridges[0].sensor_bytes = _counts(4000, status=AbpStatus.STALE)
    assert _tick(node, io, 2) == []
    assert "1 readings skipped (status STALE)" in caplog.text
    bus.bridges[0].sensor_bytes = _counts(16000)
    (value,) = _tick(node, io)
    assert value > PSI_PA
    assert "saturated: 16000 counts outside 1638..14745" in caplog.text


def test_an_unplugged_bridge_is_reported_and_found_again(
    bus: EmulatedBackend, caplog: pytest.LogCaptureFixture
) -> None:
    node, io = _node("left", "BUBBLE-L", retry_secs=0.05)
    assert len(_tick(node, io)) == 1
    bridge = bus.bridges[0]
    bridge.unplug_after_reports = 1  # the read request goes out, then the cable is pulled
    assert len(_tick(node, io)) == 1
    assert "the bridge is gone (unplugged?)" in caplog.text
    assert "retrying every 0.05 s" in caplog.text
    time.sleep(0.06)
    assert len(_tick(node, io, 3)) == 1  # still unplugged: nothing, and no crash
    bridge.plugged, bridge.unplug_after_reports = True, -1
    bridge.kernel_driver = True  # the kernel binds a replugged device again
    time.sleep(0.06)
    assert len(_tick(node, io, 2)) == 3
    assert "MCP2221A 'BUBBLE-L' is back after" in caplog.text


def test_access_denied_names_the_udev_rule(bus: EmulatedBackend) -> None:
    bus.bridges[1].access_denied = True
    with pytest.raises(NodeError, match=r'right: .*ATTRS\{idVendor\}=="04d8".*99-mcp2221.rules'):
        _node("right", "BUBBLE-R")


def test_a_missing_serial_lists_what_is_plugged_in(bus: EmulatedBackend) -> None:
    with pytest.raises(NodeError, match="need serial 'NOPE'; plugged in: 'BUBBLE-L', 'BUBBLE-R'"):
        _node("left", "NOPE")
    with pytest.raises(NodeError, match="need exactly one bridge"):
        _node("left", "")


def test_a_sensor_at_another_address_does_not_answer(bus: EmulatedBackend) -> None:
    node, io = _node("left", "BUBBLE-L", address=0x38)
    assert _tick(node, io) == []
    assert node.failures == 1
