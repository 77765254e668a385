"""Stable-grasp detection from the bubbles' pressure rise and the finger speed.

The paper calls a grasp stable from "thresholds on the bubble pressure differential as
well as the finger velocity"; the shear reference, the classifier's frames and the
tasks all key off that moment. This module is the detector, with no sockets:

- each bubble's pressure is low-pass filtered (first order, ``filter_secs``) so that
  sensor noise does not cross thresholds;
- each bubble has a *free baseline*: the filtered pressure while that bubble is out of
  contact, tracked slowly (``baseline_secs``) so that drift (temperature, a slow leak)
  does not read as contact; it freezes during contact;
- a bubble is in contact when its rise over the baseline exceeds ``contact_rise_pa`` and
  stays in contact until the rise falls under ``release_rise_pa`` (hysteresis);
- the grasp is *stable* once both bubbles are in contact and the finger speed has stayed
  under ``still_speed_m_per_s`` for ``dwell_secs``;
- a stable grasp is *released* when either bubble leaves contact or the fingers open by
  more than ``release_opening_m`` from the tightest width seen while stable; becoming
  stable again takes a full dwell. A force-controlled gripper that squeezes a little
  further (an object slipping, a person pulling in a handover) keeps the grasp: ending
  it there would drop the shear reference exactly when the shear matters.

Times are the messages' stamps (nanoseconds), so replayed bags give the same events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
from msgspec import Meta

# What happened to the grasp at a sample (``GraspState.event`` on the wire).
GraspEvent = Literal["", "stable", "released"]

SENSORS = ("left", "right")


class GraspParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Thresholds of the stable-grasp detector.

    The paper gives no values. Defaults assume the simulated bubble (about 1 kPa of
    inflation, docs/facts.md), where a firm grasp raises the pressure by a few percent.
    """

    contact_rise_pa: Annotated[
        float, Meta(gt=0, description="rise over the free baseline that starts contact.")
    ] = 30.0
    release_rise_pa: Annotated[
        float, Meta(ge=0, description="rise under which contact ends (< ``contact_rise_pa``).")
    ] = 15.0
    still_speed_m_per_s: Annotated[
        float, Meta(gt=0, description="finger speed under which the fingers count as still.")
    ] = 0.002
    release_opening_m: Annotated[
        float,
        Meta(gt=0, description="opening beyond the tightest stable width that ends the grasp."),
    ] = 0.002
    dwell_secs: Annotated[
        float,
        Meta(
            ge=0, description="how long contact and stillness must last before the grasp is stable."
        ),
    ] = 0.3
    filter_secs: Annotated[
        float, Meta(ge=0, description="time constant of the pressure low-pass filter (0: none).")
    ] = 0.05
    baseline_secs: Annotated[
        float, Meta(gt=0, description="time constant of the free-baseline tracker.")
    ] = 2.0
    baseline_pa: Annotated[
        float | None,
        Meta(
            description=(
                "a fixed free baseline for both bubbles instead of tracking one (None: "
                "track; the first sample starts the baseline)."
            )
        ),
    ] = None

    def __post_init__(self) -> None:
        if not self.release_rise_pa < self.contact_rise_pa:
            raise ValueError(
                f"`release_rise_pa` must be < contact_rise_pa ({self.contact_rise_pa}), "
                f"got {self.release_rise_pa!r}"
            )


@dataclass(frozen=True)
class GraspStatus:
    """What the detector says after one sample.

    Attributes:
        stable: the grasp is stable now.
        event: ``"stable"`` at the sample where it became stable, ``"released"`` where a
            stable grasp ended, ``""`` otherwise.
        contact_left, contact_right: each bubble's contact state (with hysteresis).
        pressure_rise_left_pa, pressure_rise_right_pa: filtered rise over each baseline.
        finger_speed_m_per_s: the last finger speed (absolute).
        width_m: the last jaw opening (NaN before the first gripper sample).
        stamp_nanos: the stamp of the sample.
    """

    stable: bool
    event: GraspEvent
    contact_left: bool
    contact_right: bool
    pressure_rise_left_pa: float
    pressure_rise_right_pa: float
    finger_speed_m_per_s: float
    width_m: float
    stamp_nanos: int


class _Bubble:
    """One bubble's filtered pressure, free baseline and contact state."""

    def __init__(self, params: GraspParams) -> None:
        self.params = params
        self.filtered: float | None = None
        self.baseline: float | None = params.baseline_pa
        self.contact = False
        self.stamp: int | None = None

    @property
    def rise_pa(self) -> float:
        if self.filtered is None or self.baseline is None:
            return 0.0
        return self.filtered - self.baseline

    def update(self, pressure_pa: float, stamp_nanos: int) -> None:
        if not math.isfinite(pressure_pa):
            return  # a dropped reading changes nothing
        p = self.params
        dt = 0.0 if self.stamp is None else max(0.0, (stamp_nanos - self.stamp) * 1e-9)
        self.stamp = stamp_nanos if self.stamp is None else max(self.stamp, stamp_nanos)
        if self.filtered is None or p.filter_secs == 0.0:
            self.filtered = pressure_pa
        else:
            alpha = 1.0 - math.exp(-dt / p.filter_secs)
            self.filtered += alpha * (pressure_pa - self.filtered)
        if self.baseline is None:
            self.baseline = self.filtered
        rise = self.rise_pa
        if self.contact:
            self.contact = rise >= p.release_rise_pa
        else:
            self.contact = rise > p.contact_rise_pa
        # The baseline follows only a free bubble whose rise is under the release
        # threshold, so a slow squeeze is not absorbed into it.
        if p.baseline_pa is None and not self.contact and rise < p.release_rise_pa:
            beta = 1.0 - math.exp(-dt / p.baseline_secs)
            self.baseline += beta * (self.filtered - self.baseline)


class GraspMonitor:
    """The stable-grasp state machine; feed it pressure and gripper samples in any order."""

    def __init__(self, params: GraspParams | None = None) -> None:
        self.params = params or GraspParams()
        self._bubbles = {sensor: _Bubble(self.params) for sensor in SENSORS}
        self._speed: float | None = None
        self._width: float = math.nan
        self._tightest: float = math.nan
        self._still_since: int | None = None
        self._now: int | None = None
        self.stable = False

    def update_pressure(self, sensor: str, pressure_pa: float, stamp_nanos: int) -> GraspStatus:
        """A bubble's gauge pressure sample.

        Raises:
            ValueError: ``sensor`` is not ``"left"`` or ``"right"``.
        """
        if sensor not in self._bubbles:
            raise ValueError(f"`sensor` must be one of {SENSORS}, got {sensor!r}")
        self._bubbles[sensor].update(pressure_pa, stamp_nanos)
        return self._step(stamp_nanos)

    def update_gripper(self, speed_m_per_s: float, width_m: float, stamp_nanos: int) -> GraspStatus:
        """A gripper sample: finger speed (sign ignored; non-finite counts as moving) and
        jaw opening (non-finite is ignored)."""
        self._speed = abs(speed_m_per_s) if math.isfinite(speed_m_per_s) else math.inf
        if math.isfinite(width_m):
            self._width = width_m
        return self._step(stamp_nanos)

    def status(self, event: GraspEvent = "") -> GraspStatus:
        """The current state without a new sample."""
        left, right = self._bubbles["left"], self._bubbles["right"]
        return GraspStatus(
            stable=self.stable,
            event=event,
            contact_left=left.contact,
            contact_right=right.contact,
            pressure_rise_left_pa=left.rise_pa,
            pressure_rise_right_pa=right.rise_pa,
            finger_speed_m_per_s=0.0 if self._speed is None else min(self._speed, 1e9),
            width_m=self._width,
            stamp_nanos=self._now or 0,
        )

    def _step(self, stamp_nanos: int) -> GraspStatus:
        self._now = stamp_nanos if self._now is None else max(self._now, stamp_nanos)
        now = self._now
        p = self.params
        contact = all(b.contact for b in self._bubbles.values())
        speed = self._speed
        still = speed is not None and speed < p.still_speed_m_per_s
        event: GraspEvent = ""
        if self.stable:
            if not math.isfinite(self._tightest) or self._width < self._tightest:
                self._tightest = self._width
            # NaN compares False: without a width no opening is seen.
            opened = self._width > self._tightest + p.release_opening_m
            if not contact or opened:
                self.stable = False
                self._still_since = None
                event = "released"
        if not self.stable and not event:
            if contact and still:
                if self._still_since is None:
                    self._still_since = now
                if (now - self._still_since) * 1e-9 >= p.dwell_secs:
                    self.stable = True
                    self._tightest = self._width
                    event = "stable"
            else:
                self._still_since = None
        return self.status(event)
