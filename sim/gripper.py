"""WSG 50 finger motion: commands, a speed limit, force-controlled grasps.

With the ``gripper`` effect the jaw opening moves at ``min(commanded, max)`` speed, so a
grasp takes time and finger speed is observable; ``grasp`` closes until the contact
force reaches the commanded force (found by bisection inside the last step), then
holds it, closing further if the object moves and the force drops. Without the effect
the fingers are ideal position servos: every command jumps to its ``width_m``.

Commands (as ``messages.types.GripperCommand``): ``move`` to a width (stops, blocked,
if the force exceeds the force limit), ``grasp`` (close on the part with a force),
``release`` (open to a width), ``stop``, ``home`` (open fully).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from sim.rig import GRIPPER_COMMANDS, GripperSpec


@dataclass
class FingerState:
    """The jaws now. ``speed_m_per_s`` is the magnitude of the opening's rate of change."""

    width_m: float
    speed_m_per_s: float = 0.0
    force_n: float = 0.0
    state: str = "idle"  # idle | moving | holding | fault


class GripperDynamics:
    """Integrates the opening of the jaws (see the module docstring)."""

    def __init__(self, spec: GripperSpec, *, speed_limited: bool) -> None:
        self.spec = spec
        self.speed_limited = speed_limited
        self.finger = FingerState(width_m=spec.initial_width_m)
        self._mode = "stop"
        self._target_m = spec.initial_width_m
        self._speed = 0.0
        self._force = 0.0

    @property
    def target_m(self) -> float:
        """Where the running motion ends (a grasp's target is closed, 0, under force control)."""
        return self._target_m

    def command(
        self, command: str, *, width_m: float, speed_m_per_s: float, force_n: float
    ) -> None:
        """Accept a command; unknown names raise ``ValueError`` listing the valid ones."""
        if command not in GRIPPER_COMMANDS:
            raise ValueError(
                f"unknown gripper command {command!r}; valid: {', '.join(GRIPPER_COMMANDS)}"
            )
        spec = self.spec
        self._mode = command
        self._speed = min(max(speed_m_per_s, 1e-6), spec.max_speed_m_per_s)
        self._force = min(max(force_n, 0.0), spec.max_force_n)
        if command == "home":
            self._target_m = spec.max_width_m
            self._speed = spec.max_speed_m_per_s
        elif command in ("move", "release"):
            self._target_m = min(max(width_m, 0.0), spec.max_width_m)
        elif command == "grasp":
            # Ideal servo: go to the part's width; force control: close onto it.
            self._target_m = (
                min(max(width_m, 0.0), spec.max_width_m) if not self.speed_limited else 0.0
            )
        if command == "stop":
            self.finger.state = "holding" if self.finger.state == "holding" else "idle"
        else:
            self.finger.state = "moving"

    def step(self, dt_secs: float, force_at: Callable[[float], float] | None) -> FingerState:
        """Advance ``dt_secs``; ``force_at(width)`` is the contact force at an opening."""
        f = self.finger
        old = f.width_m
        if not self.speed_limited:
            if self._mode != "stop":
                f.width_m = self._target_m
                f.state = "holding" if self._mode == "grasp" else "idle"
                self._mode = "stop"
            f.speed_m_per_s = 0.0
            f.force_n = force_at(f.width_m) if force_at is not None else 0.0
            return f
        if self._mode == "grasp" and force_at is not None:
            self._step_grasp(dt_secs, force_at)
        elif self._mode in ("move", "release", "home"):
            step = self._speed * dt_secs
            delta = self._target_m - f.width_m
            new = (
                self._target_m
                if abs(delta) <= step
                else f.width_m + step * (1 if delta > 0 else -1)
            )
            if force_at is not None and self._mode == "move" and new < f.width_m:
                limit = self._force if self._force > 0 else self.spec.max_force_n
                if force_at(new) > limit:
                    new = _bisect_width(force_at, new, f.width_m, limit)
                    self._mode = "stop"
            f.width_m = new
            if f.width_m == self._target_m:
                self._mode = "stop"
            f.state = "moving" if self._mode != "stop" else "idle"
        f.speed_m_per_s = abs(f.width_m - old) / dt_secs if dt_secs > 0 else 0.0
        f.force_n = force_at(f.width_m) if force_at is not None else 0.0
        return f

    def _step_grasp(self, dt: float, force_at: Callable[[float], float]) -> None:
        f = self.finger
        # Hold with a little hysteresis, as the WSG's force loop does: re-close only
        # when the force has dropped by more than 10 % of its target.
        hold = 0.9 * self._force if f.state == "holding" else self._force
        if force_at(f.width_m) >= hold:
            f.state = "holding"
            return
        new = max(f.width_m - self._speed * dt, 0.0)
        if force_at(new) >= self._force:
            f.width_m = _bisect_width(force_at, new, f.width_m, self._force)
            f.state = "holding"
        elif new <= 0.0:
            # Closed completely without reaching the force: no part (WSG: "no part found").
            f.width_m = 0.0
            f.state = "fault"
            self._mode = "stop"
        else:
            f.width_m = new
            f.state = "moving" if f.state != "holding" else "holding"


def _bisect_width(
    force_at: Callable[[float], float], closed_m: float, open_m: float, force_n: float
) -> float:
    """The widest opening in ``[closed, open]`` where the force reaches ``force_n``."""
    lo, hi = closed_m, open_m  # force(lo) >= force_n > force(hi)
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        if force_at(mid) >= force_n:
            lo = mid
        else:
            hi = mid
    return lo
