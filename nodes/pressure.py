"""One bubble's pressure sensor: ``pressure.sim`` and ``pressure.usb``.

``pressure.sim``
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``.
    outputs: ``pressure`` (Pressure): gauge pascals, one per world state, with its
        stamp, when the scene lists ``pressure`` (nothing otherwise).
    The pressure itself (ideal gas at constant temperature, ``sim.pressure``) is part
    of the world's mechanics, since the grip force follows from it; this node reports it.

``pressure.usb``
    outputs: ``pressure`` (Pressure): gauge pascals from a Honeywell ABP sensor read
        over I2C through a Microchip MCP2221A USB bridge (``devices.abp``,
        ``devices.mcp2221``), ``rate_hz`` times a second, stamped with the wall clock.
    The bridge is found by its USB serial number (two bubbles: two bridges). Setup
    fails with what to do when no bridge matches or access is denied (the udev rule).
    An unplugged bridge is reported and looked for every ``retry_secs`` until it is
    back; three failed reads in a row reset the bridge. Stale readings (no conversion
    since the last read) are skipped and counted; saturated ones (counts outside the
    calibrated 10-90 %) are published and reported when they start. With a
    ``calibration`` file (made for this bridge's serial, else refused naming both) the
    sensor's zero is subtracted from every reading; without one the node says so once.
    A machine without a libusb backend gets one line saying so, not a traceback.
"""

from __future__ import annotations

import time
from typing import Annotated, Literal

import msgspec
from msgspec import Meta

from devices import mcp2221
from devices.abp import ADDRESS, COUNTS_MAX, COUNTS_MIN, PSI_PA, AbpSensor, AbpStatus, Reading
from messages.base import Header
from messages.errors import DeviceError, NodeError
from messages.sim import WorldState
from messages.types import Pressure
from perception.calibration.rigfile import CalibrationError, load_calibration
from runtime.node import Node
from runtime.registry import register
from sim import pressure
from sim.effects import resolve
from sim.wire import SensorParams, from_message


@register("pressure.sim")
class SimPressure(Node):
    """Publishes the bubble's gauge pressure (see the module docstring)."""

    Params = SensorParams
    inputs = {"world": WorldState}
    outputs = {"pressure": Pressure}

    def setup(self) -> None:
        self.warned = False

    def on_world(self, msg: WorldState) -> None:
        if "pressure" not in resolve(msg.effects):
            if not self.warned:
                self.io.log.info(
                    "%s: the scene has no pressure effect; nothing to publish", self.name
                )
                self.warned = True
            return
        snap = from_message(msg)
        self.io.publish("pressure", pressure(snap, self.params.sensor, msg.header.stamp_nanos))


class UsbPressureParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """One bubble's ABP sensor behind an MCP2221A bridge (pascals, hertz, seconds).

    ``serial``: the bridge's USB serial number ("" when only one bridge is plugged in);
    ``address``: the sensor's 7-bit I2C address; ``pmin_pa``/``pmax_pa``: the sensor's
    range (a 0..1 psi gauge part by default).
    """

    sensor: Annotated[Literal["left", "right"], Meta(description="which bubble: left or right")]
    serial: Annotated[
        str,
        Meta(description="the bridge's USB serial number ('' when only one bridge is plugged in)"),
    ] = ""
    address: Annotated[int, Meta(description="the sensor's 7-bit I2C address", gt=0, lt=128)] = (
        ADDRESS
    )
    pmin_pa: Annotated[float, Meta(description="the low end of the sensor's range")] = 0.0
    pmax_pa: Annotated[
        float,
        Meta(description="the high end of the sensor's range (a 0..1 psi gauge part by default)"),
    ] = PSI_PA
    rate_hz: Annotated[float, Meta(description="readings per second", gt=0, le=1000)] = 100.0
    i2c_speed_hz: Annotated[
        int, Meta(description="the bridge's I2C clock", ge=47000, le=400000)
    ] = 100_000
    retry_secs: Annotated[
        float, Meta(description="while the bridge is gone, look for it this often", gt=0)
    ] = 0.5
    calibration: Annotated[
        str, Meta(description="the rig's calibration file, with the sensor's zero ('' for none)")
    ] = ""

    def __post_init__(self) -> None:
        if self.calibration:
            try:
                load_calibration(self.calibration)
            except CalibrationError as err:
                raise ValueError(f"`calibration`: {err}") from err
        if not self.pmax_pa > self.pmin_pa:
            raise ValueError(
                f"`pmax_pa` must be > pmin_pa ({self.pmin_pa!r}), got {self.pmax_pa!r}"
            )


@register("pressure.usb")
class UsbPressure(Node):
    """Reads one bubble's pressure over USB (see the module docstring)."""

    Params = UsbPressureParams
    outputs = {"pressure": Pressure}

    def setup(self) -> None:
        p = self.params
        try:
            backend = mcp2221.default_backend()
        except DeviceError as err:
            raise NodeError(f"{self.name}: {err}") from err
        self.bridge = mcp2221.MCP2221(p.serial, backend=backend)
        self.sensor = AbpSensor(
            self.bridge, address=p.address, pmin_pa=p.pmin_pa, pmax_pa=p.pmax_pa
        )
        self.offset_pa = 0.0
        self.failures = 0  # consecutive failed reads
        self.stale = 0
        self.saturated = False
        self.lost_at = 0.0
        self.next_try = 0.0
        try:
            self._open()
        except DeviceError as err:
            raise NodeError(f"{self.name}: {err}") from err
        if p.calibration:
            try:
                cal = load_calibration(p.calibration).pressure_sensor(
                    p.sensor, self.bridge.device_serial
                )
            except CalibrationError as err:
                raise NodeError(f"{self.name}: calibration refused: {err}") from err
            self.offset_pa = cal.offset_pa
            zero = f"zero {cal.offset_pa:.1f} +- {cal.offset_sigma_pa:.2f} Pa from {p.calibration}"
        else:
            zero = "no calibration file: the sensor's zero is not corrected"
        self.io.log.info(
            "%s: reading %s, sensor at 0x%02x, %s", self.name, self.bridge.where, p.address, zero
        )
        self.io.add_timer(1.0 / p.rate_hz, self.tick)

    def teardown(self) -> None:
        self.bridge.disconnect()

    def _open(self) -> None:
        self.bridge.connect()
        self.bridge.set_i2c_speed(self.params.i2c_speed_hz)

    def tick(self) -> None:
        """Read once and publish; reconnect every ``retry_secs`` while the bridge is gone."""
        now = time.monotonic()
        if not self.bridge.is_connected:
            if now < self.next_try:
                return
            self.next_try = now + self.params.retry_secs
            try:
                self._open()
            except DeviceError:
                return  # still gone; reported when it went
            self.io.log.warning(
                "%s: %s is back after %.1f s", self.name, self.bridge.where, now - self.lost_at
            )
        try:
            reading = self.sensor.read()
        except mcp2221.DeviceGone as err:
            self.io.log.error("%s: %s; retrying every %g s", self.name, err, self.params.retry_secs)
            self.bridge.disconnect()
            self.lost_at, self.next_try = now, now + self.params.retry_secs
            return
        except DeviceError as err:
            self.failures += 1
            self.io.log.error("%s: %s", self.name, err)
            if self.failures >= 3:  # the bridge's I2C engine may be stuck: reset it
                self.io.log.warning("%s: resetting %s", self.name, self.bridge.where)
                self.failures = 0
                self.bridge.reset()
                self.lost_at, self.next_try = now, now + self.params.retry_secs
            return
        self.failures = 0
        self._publish(reading)

    def _publish(self, reading: Reading) -> None:
        if reading.status != AbpStatus.NORMAL:
            # Stale: no conversion since the last read (reading faster than the sensor
            # converts); command mode: not a measurement. Neither is new data.
            self.stale += 1
            if self.stale in (1, 100, 10_000):
                self.io.log.warning(
                    "%s: %d readings skipped (status %s); lower `rate_hz`?",
                    self.name,
                    self.stale,
                    reading.status.name,
                )
            return
        if reading.saturated != self.saturated:
            self.saturated = reading.saturated
            if reading.saturated:
                self.io.log.warning(
                    "%s: saturated: %d counts outside %d..%d (%.0f Pa, beyond the sensor's"
                    " range %g..%g Pa)",
                    self.name,
                    reading.counts,
                    COUNTS_MIN,
                    COUNTS_MAX,
                    reading.pressure_pa,
                    self.params.pmin_pa,
                    self.params.pmax_pa,
                )
        self.io.publish(
            "pressure",
            Pressure(
                header=Header(
                    stamp_nanos=self.io.now_nanos(), frame_id=f"{self.params.sensor}_bubble"
                ),
                sensor=self.params.sensor,
                pressure_pa=reading.pressure_pa - self.offset_pa,
            ),
        )
