"""Honeywell ABP (TruStability) board-mount pressure sensors read over I2C.

A read of two bytes returns two status bits (00 normal, 01 command mode, 10 stale data:
already read since the last conversion, 11 diagnostic fault) and 14 bits of pressure
counts. The transfer function spans 10 % to 90 % of 2^14 counts over the sensor's range
``Pmin..Pmax`` (datasheet, "I2C communications" and "transfer function")::

    P = (counts - 1638) * (Pmax - Pmin) / (14745 - 1638) + Pmin

Counts outside 1638..14745 mean a pressure beyond the calibrated range: the value is
still returned (extrapolated) and flagged ``saturated``. The default address is 0x28.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from devices.mcp2221 import MCP2221
from messages.errors import DeviceError

ADDRESS = 0x28
COUNTS_MIN = 1638  # 10 % of 2^14
COUNTS_MAX = 14745  # 90 % of 2^14
PSI_PA = 6894.757


class AbpStatus(enum.IntEnum):
    """The two status bits of a reading."""

    NORMAL = 0
    COMMAND_MODE = 1
    STALE = 2
    FAULT = 3


@dataclass(frozen=True)
class Reading:
    """One reading: pressure (pascals, gauge for a gauge sensor), raw counts, flags."""

    pressure_pa: float
    counts: int
    status: AbpStatus

    @property
    def saturated(self) -> bool:
        return not COUNTS_MIN <= self.counts <= COUNTS_MAX


def decode(data: bytes, *, pmin_pa: float, pmax_pa: float) -> Reading:
    """The reading two (or more) bytes from the sensor carry."""
    if len(data) < 2:
        raise DeviceError(f"ABP: a reading needs 2 bytes, got {data.hex(' ')!r}")
    status = AbpStatus(data[0] >> 6)
    counts = ((data[0] & 0x3F) << 8) | data[1]
    pressure = (counts - COUNTS_MIN) * (pmax_pa - pmin_pa) / (COUNTS_MAX - COUNTS_MIN) + pmin_pa
    return Reading(pressure, counts, status)


class AbpSensor:
    """An ABP gauge sensor behind an MCP2221A bridge."""

    def __init__(
        self,
        bridge: MCP2221,
        *,
        address: int = ADDRESS,
        pmin_pa: float = 0.0,
        pmax_pa: float = PSI_PA,
    ) -> None:
        if not pmax_pa > pmin_pa:
            raise ValueError(f"`pmax_pa` must be > pmin_pa ({pmin_pa!r}), got {pmax_pa!r}")
        if not 0 < address < 0x80:
            raise ValueError(f"`address` must be a 7-bit I2C address, got {address!r}")
        self.bridge = bridge
        self.address = address
        self.pmin_pa, self.pmax_pa = pmin_pa, pmax_pa

    def read(self) -> Reading:
        """One reading; a diagnostic fault raises :class:`DeviceError`."""
        reading = decode(
            self.bridge.i2c_read(self.address, 2), pmin_pa=self.pmin_pa, pmax_pa=self.pmax_pa
        )
        if reading.status == AbpStatus.FAULT:
            raise DeviceError(
                f"{self.bridge.where}: ABP sensor at 0x{self.address:02x} reports a diagnostic"
                " fault (status bits 11: a broken bridge circuit or supply; check its wiring)"
            )
        return reading
