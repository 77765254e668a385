"""A pyusb backend that emulates MCP2221A bridges with Honeywell ABP sensors behind them.

Used by the tests of ``pressure.usb`` and by ``python -m bench.drivers``.

It works at the USB transfer level (``usb.backend.IBackend``): descriptors, string
descriptors over control transfers, a kernel driver bound to the HID interface, and
64-byte interrupt reports answered as the MCP2221A datasheet describes. Behind each
bridge an ABP sensor answers 2-byte I2C reads at its address. A bridge can be
unplugged (transfers fail with ENODEV, as libusb reports it) and plugged in again, and
can deny access (EACCES), so the driver's real pyusb code meets each of these.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import usb.backend
import usb.core

from devices.abp import COUNTS_MAX, COUNTS_MIN

EP_OUT, EP_IN, HID_INTERFACE = 0x03, 0x83, 2


def abp_bytes(pressure_pa: float, *, pmin_pa: float, pmax_pa: float, status: int = 0) -> bytes:
    """What an ABP sensor sends for a pressure (counts rounded, clipped to 14 bits)."""
    span = (pressure_pa - pmin_pa) * (COUNTS_MAX - COUNTS_MIN) / (pmax_pa - pmin_pa)
    counts = min(max(int(round(COUNTS_MIN + span)), 0), 0x3FFF)
    return bytes([(status << 6) | (counts >> 8), counts & 0xFF])


@dataclass
class EmulatedBridge:
    """One MCP2221A and its sensor: ``sensor_bytes`` is what the next read returns."""

    serial: str
    device: str = ""  # its name on an emulated rig (``sim.emulated_rig``: its plug)
    sensor_address: int = 0x28
    sensor_bytes: bytes = b"\x06\x66"  # 1638 counts: Pmin
    plugged: bool = True
    access_denied: bool = False
    kernel_driver: bool = True
    unplug_after_reports: int = -1  # >= 0: unplug after that many more reports
    reads: int = 0
    speed_divider: int = 0
    _pending: bytes | None = None
    _failed: bool = False
    claimed: set[int] = field(default_factory=set)

    def answer(self, report: bytes) -> bytes:
        """The bridge's 64-byte answer to one report (the datasheet's HID commands)."""
        out = bytearray(64)
        out[0] = report[0]
        if report[0] == 0x10:
            if report[2] == 0x10:
                self._pending, self._failed = None, False
            if report[3] == 0x20:
                self.speed_divider = report[4]
                out[3] = 0x20
        elif report[0] == 0x91:
            length = report[1] | (report[2] << 8)
            if (report[3] >> 1) == self.sensor_address and report[3] & 1:
                self._pending, self._failed = self.sensor_bytes[:length], False
                self.reads += 1
            else:
                self._pending, self._failed = None, True  # no acknowledge
        elif report[0] == 0x40:
            if self._failed or self._pending is None:
                out[1], out[2], out[3] = 0x41, 0x25, 127
            else:
                out[3] = len(self._pending)
                out[4 : 4 + len(self._pending)] = self._pending
                self._pending = None
        else:
            out[1] = 0x01
        return bytes(out)


def _device_desc(index: int, bridge: EmulatedBridge) -> SimpleNamespace:
    return SimpleNamespace(
        bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
        bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=0x04D8, idProduct=0x00DD,
        bcdDevice=0x0100, iManufacturer=1, iProduct=2, iSerialNumber=3,
        bNumConfigurations=1, address=10 + index, bus=1, port_number=index + 1,
        port_numbers=(index + 1,), speed=2,
    )  # fmt: skip


_CONFIG = SimpleNamespace(
    bLength=9, bDescriptorType=2, wTotalLength=107, bNumInterfaces=3, bConfigurationValue=1,
    iConfiguration=0, bmAttributes=0x80, bMaxPower=50, extra_descriptors=[],
)  # fmt: skip


def _interface(number: int) -> SimpleNamespace:
    klass, endpoints = {0: (2, 1), 1: (10, 2), 2: (3, 2)}[number]  # CDC, CDC data, HID
    return SimpleNamespace(
        bLength=9, bDescriptorType=4, bInterfaceNumber=number, bAlternateSetting=0,
        bNumEndpoints=endpoints, bInterfaceClass=klass, bInterfaceSubClass=0,
        bInterfaceProtocol=0, iInterface=0, extra_descriptors=[],
    )  # fmt: skip


def _endpoint(intf: int, index: int) -> SimpleNamespace:
    address = {(0, 0): 0x82, (1, 0): 0x01, (1, 1): 0x81, (2, 0): EP_IN, (2, 1): EP_OUT}
    return SimpleNamespace(
        bLength=7, bDescriptorType=5, bEndpointAddress=address[(intf, index)],
        bmAttributes=3 if intf != 1 else 2, wMaxPacketSize=64, bInterval=1, bRefresh=0,
        bSynchAddress=0, extra_descriptors=[],
    )  # fmt: skip


def _gone() -> usb.core.USBError:
    return usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)


class EmulatedBackend(usb.backend.IBackend):  # type: ignore[misc]
    """The bridges plugged into an emulated USB bus (see the module docstring)."""

    def __init__(self, *bridges: EmulatedBridge) -> None:
        super().__init__()
        self.bridges = list(bridges)
        self._answers: dict[int, bytes] = {}

    def enumerate_devices(self) -> Any:
        return [i for i, b in enumerate(self.bridges) if b.plugged]

    def get_device_descriptor(self, dev: int) -> Any:
        return _device_desc(dev, self.bridges[dev])

    def get_configuration_descriptor(self, dev: int, config: int) -> Any:
        if config != 0:
            raise IndexError(config)
        return _CONFIG

    def get_interface_descriptor(self, dev: int, intf: int, alt: int, config: int) -> Any:
        if alt != 0 or intf > 2:
            raise IndexError((intf, alt))
        return _interface(intf)

    def get_endpoint_descriptor(self, dev: int, ep: int, intf: int, alt: int, config: int) -> Any:
        return _endpoint(intf, ep)

    def _bridge(self, handle: int) -> EmulatedBridge:
        bridge = self.bridges[handle]
        if not bridge.plugged:
            raise _gone()
        return bridge

    def open_device(self, dev: int) -> int:
        if self.bridges[dev].access_denied:
            raise usb.core.USBError("Access denied (insufficient permissions)", -3, errno.EACCES)
        self._bridge(dev)
        return dev

    def close_device(self, dev_handle: int) -> None:
        pass

    def set_configuration(self, dev_handle: int, config_value: int) -> None:
        self._bridge(dev_handle)

    def get_configuration(self, dev_handle: int) -> int:
        self._bridge(dev_handle)
        return 1

    def claim_interface(self, dev_handle: int, intf: int) -> None:
        bridge = self._bridge(dev_handle)
        if intf == HID_INTERFACE and bridge.kernel_driver:
            raise usb.core.USBError("Resource busy", -6, errno.EBUSY)
        bridge.claimed.add(intf)

    def release_interface(self, dev_handle: int, intf: int) -> None:
        self._bridge(dev_handle).claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle: int, intf: int) -> bool:
        return intf == HID_INTERFACE and self._bridge(dev_handle).kernel_driver

    def detach_kernel_driver(self, dev_handle: int, intf: int) -> None:
        self._bridge(dev_handle).kernel_driver = False

    def ctrl_transfer(
        self, dev_handle: int, bmRequestType: int, bRequest: int, wValue: int, wIndex: int,
        data: Any, timeout: int,
    ) -> int:  # fmt: skip
        bridge = self._bridge(dev_handle)
        if bRequest != 0x06 or wValue >> 8 != 3:
            raise usb.core.USBError("Pipe error", -9, errno.EPIPE)
        index = wValue & 0xFF
        if index == 0:
            desc = bytes([4, 3, 0x09, 0x04])  # language: English (US)
        else:
            text = {1: "Microchip Technology Inc.", 2: "MCP2221 USB-I2C/UART Combo"}.get(
                index, bridge.serial
            )
            encoded = text.encode("utf-16-le")
            desc = bytes([2 + len(encoded), 3]) + encoded
        n = min(len(desc), len(data))
        data[:n] = type(data)(data.typecode, desc[:n])
        return n

    def intr_write(self, dev_handle: int, ep: int, intf: int, data: Any, timeout: int) -> int:
        bridge = self._bridge(dev_handle)
        if ep != EP_OUT or intf not in bridge.claimed:
            raise usb.core.USBError("Invalid parameter", -2, errno.EINVAL)
        if bridge.unplug_after_reports == 0:
            bridge.plugged = False
            raise _gone()
        bridge.unplug_after_reports -= 1
        report = bytes(data)
        if report[0] == 0x70 and report[1:4] == b"\xab\xcd\xef":
            bridge.claimed.clear()
            bridge.kernel_driver = True  # it re-enumerates: the kernel binds it again
            return len(report)
        self._answers[dev_handle] = bridge.answer(report)
        return len(report)

    def intr_read(self, dev_handle: int, ep: int, intf: int, buff: Any, timeout: int) -> int:
        bridge = self._bridge(dev_handle)
        if bridge.unplug_after_reports == 0:
            bridge.plugged = False
            raise _gone()
        answer = self._answers.pop(dev_handle, None)
        if answer is None:
            raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        buff[: len(answer)] = type(buff)(buff.typecode, answer)
        return len(answer)
