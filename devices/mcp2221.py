"""The Microchip MCP2221A USB-to-I2C bridge over pyusb: discovery, HID reports, I2C.

The bridge is a USB HID device (vendor 0x04D8, product 0x00DD) whose HID interface has
one interrupt endpoint each way; every exchange is a 64-byte report out and a 64-byte
report back, the first byte naming the command (datasheet, "USB HID commands"):

* ``0x10`` status / set parameters: byte 2 = 0x10 cancels a stuck I2C transfer,
  byte 3 = 0x20 sets the I2C clock to ``12 MHz / (byte 4 + 3)``;
* ``0x91`` I2C read: length (u16 LE), then the 7-bit address shifted left with the
  read bit; the answer's byte 1 is 0x00 when the transfer started (0x01: engine busy);
* ``0x40`` get I2C data: byte 1 0x00 and byte 3 the count, data from byte 4 (0x41 or
  a count of 127: the read failed, e.g. no device acknowledged the address);
* ``0x70`` reset (0xAB 0xCD 0xEF), used to recover a bridge whose I2C engine stays
  stuck. (``0x90`` I2C write exists too; a gauge sensor needs none.)

Several bridges (one per bubble) are told apart by their USB serial number. Linux binds
the kernel's HID driver to the interface: it is detached before claiming. Errors name
what to do: a permission error the udev rule to add, an unplugged bridge
:class:`DeviceGone` (the caller rediscovers it by serial and retries).
"""

from __future__ import annotations

import errno
import importlib
import os
import time
from typing import Any

import usb.core
import usb.util

from devices.base import Device
from messages.errors import DeviceError

VENDOR_ID = 0x04D8
PRODUCT_ID = 0x00DD
REPORT_SIZE = 64
HID_CLASS = 3
CLOCK_HZ = 12_000_000

STATUS = 0x10
I2C_READ = 0x91
GET_I2C_DATA = 0x40
RESET = 0x70
CANCEL_TRANSFER = 0x10
SET_SPEED = 0x20
READ_FAILED = 0x41
FAILED_COUNT = 127
BACKEND_ENV = "SOFTBUBBLE_USB_BACKEND"

UDEV_RULE = (
    'SUBSYSTEM=="usb", ATTRS{idVendor}=="04d8", ATTRS{idProduct}=="00dd", '
    'MODE="0660", GROUP="plugdev"'
)
UDEV_HINT = (
    f"add the udev rule `{UDEV_RULE}` to /etc/udev/rules.d/99-mcp2221.rules, run"
    " `sudo udevadm control --reload-rules && sudo udevadm trigger`, be in the plugdev"
    " group, and replug the bridge"
)


class DeviceGone(DeviceError):
    """The bridge disappeared (unplugged) during a transfer."""


class BridgeNotFound(DeviceError):
    """No bridge with the wanted serial number is plugged in."""


def default_backend() -> Any:
    """A libusb-1.0 backend for pyusb: the one the ``libusb-package`` wheel ships.

    ``$SOFTBUBBLE_USB_BACKEND`` (``module:function``) names another backend's factory
    instead: the emulated rig's (``sim.emulated_rig:usb_backend``) is how the hardware
    graph's own pressure node reads emulated bridges.

    Raises:
        DeviceError: neither that library nor the system's libusb-1.0 loads.
    """
    named = os.environ.get(BACKEND_ENV, "")
    if named:
        module, _, factory = named.partition(":")
        try:
            return getattr(importlib.import_module(module), factory)()
        except (ImportError, AttributeError, ValueError) as err:
            raise DeviceError(f"${BACKEND_ENV}={named!r}: no such backend factory ({err})") from err
    try:
        import libusb_package

        backend = libusb_package.get_libusb1_backend()
        wheel = "the `libusb-package` wheel's library did not load"
    except ImportError:
        backend, wheel = None, "the `libusb-package` wheel is not installed"
    if backend is None:
        import usb.backend.libusb1

        backend = usb.backend.libusb1.get_backend()
    if backend is None:
        raise DeviceError(
            f"pyusb has no libusb-1.0 backend: {wheel} and neither did the system's"
            " libusb-1.0 (is this a machine with a USB subsystem, /dev/bus/usb?)"
        )
    return backend


def _usb_error(err: usb.core.USBError, what: str) -> DeviceError:
    """A pyusb error as one of ours, with what to do about it."""
    if err.errno == errno.EACCES:
        return DeviceError(f"{what}: permission denied: {UDEV_HINT}")
    if err.errno in (errno.ENODEV, errno.ENOENT, errno.EPIPE) or err.backend_error_code == -4:
        return DeviceGone(f"{what}: the bridge is gone (unplugged?): {err}")
    return DeviceError(f"{what}: USB error: {err}")


def find_bridges(backend: Any = None) -> dict[str, Any]:
    """Every plugged-in bridge by serial number (``usb.core.Device`` values)."""
    backend = backend if backend is not None else default_backend()
    found: dict[str, Any] = {}
    for dev in usb.core.find(
        find_all=True, idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend
    ):
        where = f"MCP2221A on bus {dev.bus} address {dev.address}"
        try:
            serial = usb.util.get_string(dev, dev.iSerialNumber) or ""
        except usb.core.USBError as err:
            raise _usb_error(err, f"{where}: reading its serial number") from err
        except ValueError as err:  # pyusb: no langid, which is what no permission looks like
            raise DeviceError(
                f"{where}: cannot read its serial number ({err}): {UDEV_HINT}"
            ) from err
        found[serial] = dev
    return found


class MCP2221(Device):
    """One bridge, chosen by serial number; :meth:`connect` claims its HID interface."""

    def __init__(self, serial: str = "", *, backend: Any = None, timeout_ms: int = 100) -> None:
        self.serial = serial
        self.backend = backend
        self.timeout_ms = timeout_ms
        self.device: Any = None
        self.device_serial = serial  # the serial of the bridge found (when none was asked)
        self._interface = -1
        self._ep_out: Any = None
        self._ep_in: Any = None
        self.where = f"MCP2221A {serial!r}" if serial else "MCP2221A"

    @property
    def is_connected(self) -> bool:
        return self.device is not None

    def connect(self) -> None:
        """Find the bridge, detach the kernel's HID driver, claim the interface."""
        bridges = find_bridges(self.backend)
        if self.serial:
            dev = bridges.get(self.serial)
        elif len(bridges) == 1:
            self.device_serial, dev = next(iter(bridges.items()))
        else:
            dev = None
        if dev is None:
            listed = ", ".join(repr(s) for s in sorted(bridges)) or "none"
            need = f"serial {self.serial!r}" if self.serial else "exactly one bridge (or a serial)"
            raise BridgeNotFound(
                f"{self.where}: need {need}; plugged in: {listed}"
                f" (check the cable; `lsusb -d {VENDOR_ID:04x}:{PRODUCT_ID:04x}` lists them)"
            )
        try:
            dev.set_configuration()
            config = dev.get_active_configuration()
            intf = usb.util.find_descriptor(config, bInterfaceClass=HID_CLASS)
            if intf is None:
                raise DeviceError(f"{self.where}: no HID interface")
            number = intf.bInterfaceNumber
            if dev.is_kernel_driver_active(number):
                dev.detach_kernel_driver(number)
            usb.util.claim_interface(dev, number)
        except usb.core.USBError as err:
            raise _usb_error(err, f"{self.where}: opening") from err
        direction = usb.util.endpoint_direction
        self._ep_out = usb.util.find_descriptor(
            intf, custom_match=lambda e: direction(e.bEndpointAddress) == usb.util.ENDPOINT_OUT
        )
        self._ep_in = usb.util.find_descriptor(
            intf, custom_match=lambda e: direction(e.bEndpointAddress) == usb.util.ENDPOINT_IN
        )
        if self._ep_out is None or self._ep_in is None:
            raise DeviceError(f"{self.where}: the HID interface lacks an endpoint")
        self.device, self._interface = dev, number

    def disconnect(self) -> None:
        """Release the interface and the device (nothing to do once it is gone)."""
        dev, self.device = self.device, None
        if dev is None:
            return
        try:
            usb.util.release_interface(dev, self._interface)
        except usb.core.USBError:
            pass  # unplugged: nothing left to release
        usb.util.dispose_resources(dev)

    def exchange(self, report: bytes) -> bytes:
        """Send one report (padded to 64 bytes), return the bridge's 64-byte answer."""
        if self.device is None:
            raise DeviceError(f"{self.where}: not connected")
        out = bytes(report).ljust(REPORT_SIZE, b"\x00")
        try:
            self._ep_out.write(out, self.timeout_ms)
            answer = bytes(self._ep_in.read(REPORT_SIZE, self.timeout_ms))
        except usb.core.USBTimeoutError as err:
            raise DeviceError(
                f"{self.where}: no answer to command 0x{out[0]:02x} within {self.timeout_ms} ms"
            ) from err
        except usb.core.USBError as err:
            raise _usb_error(err, f"{self.where}: command 0x{out[0]:02x}") from err
        if len(answer) != REPORT_SIZE or answer[0] != out[0]:
            raise DeviceError(
                f"{self.where}: answer {answer[:4].hex(' ')}... does not echo command 0x{out[0]:02x}"
            )
        return answer

    def set_i2c_speed(self, speed_hz: int) -> None:
        """Set the I2C clock (and cancel any stuck transfer)."""
        divider = round(CLOCK_HZ / speed_hz) - 3
        if not 0 < divider < 256:
            raise ValueError(f"`speed_hz` must be in 47 kHz..400 kHz, got {speed_hz!r}")
        answer = self.exchange(bytes([STATUS, 0, CANCEL_TRANSFER, SET_SPEED, divider]))
        if answer[3] not in (0x00, SET_SPEED):
            raise DeviceError(f"{self.where}: I2C speed not set (status 0x{answer[3]:02x})")

    def cancel(self) -> None:
        """Cancel the current I2C transfer (frees a bus left busy by a failed read)."""
        self.exchange(bytes([STATUS, 0, CANCEL_TRANSFER]))

    def i2c_read(self, address: int, length: int, *, polls: int = 5) -> bytes:
        """Read ``length`` bytes from the 7-bit ``address``."""
        if not 0 < length <= REPORT_SIZE - 4:
            raise ValueError(f"`length` must be in 1..60, got {length!r}")
        request = bytes([I2C_READ, length & 0xFF, length >> 8, (address << 1) | 1])
        if self.exchange(request)[1] != 0x00:
            self.cancel()  # the engine was busy: free it and try once more
            if self.exchange(request)[1] != 0x00:
                raise DeviceError(
                    f"{self.where}: I2C engine busy; read from 0x{address:02x} refused"
                )
        answer = b""
        for _ in range(polls):
            answer = self.exchange(bytes([GET_I2C_DATA]))
            if answer[1] == 0x00 and answer[3] == length:
                return answer[4 : 4 + length]
            if answer[3] == FAILED_COUNT:
                break
            time.sleep(0.001)  # the read is still on the bus
        self.cancel()
        raise DeviceError(
            f"{self.where}: I2C read of {length} bytes from 0x{address:02x} failed"
            f" (status 0x{answer[1]:02x}, state 0x{answer[2]:02x}, count {answer[3]}):"
            " is the sensor wired to SDA/SCL, powered, and at that address?"
        )

    def reset(self) -> None:
        """Reset the chip (it re-enumerates: connect again afterwards)."""
        if self.device is None:
            raise DeviceError(f"{self.where}: not connected")
        try:
            self._ep_out.write(bytes([RESET, 0xAB, 0xCD, 0xEF]).ljust(REPORT_SIZE, b"\0"))
        except usb.core.USBError as err:
            raise _usb_error(err, f"{self.where}: reset") from err
        self.disconnect()
