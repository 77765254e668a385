"""Stable-grasp detection (perception/grasp.py): on the simulator's grasps, and on
scripted pressure traces for the edge cases (thresholds, noise, drift)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

import sim
from perception.grasp import GraspMonitor, GraspParams
from runtime.params import build_params

RATE_HZ = 100.0
BASE_PA = 1000.0


@dataclass(frozen=True)
class Grasp:
    """A scripted grasp: fingers close, touch, squeeze, hold, then open.

    Times in seconds. The pressure of each bubble rises linearly from contact until the
    fingers stop, then holds; opening drops it back linearly.
    """

    close_at: float = 0.5
    contact_at: float = 0.8
    stop_at: float = 1.0
    open_at: float = 3.0
    end_at: float = 4.0
    rise_pa: float = 80.0
    speed_m_per_s: float = 0.02
    noise_pa: float = 0.0
    right_rise_pa: float | None = None
    seed: int = 0

    def samples(self):
        """Yield ``(t, left_pa, right_pa, speed, width)`` at RATE_HZ."""
        rng = np.random.default_rng(self.seed)
        right_rise = self.rise_pa if self.right_rise_pa is None else self.right_rise_pa
        width = 0.1
        for i in range(int(self.end_at * RATE_HZ)):
            t = i / RATE_HZ
            if self.close_at <= t < self.stop_at:
                speed = -self.speed_m_per_s
            elif self.open_at <= t < self.open_at + 0.5:
                speed = self.speed_m_per_s
            else:
                speed = 0.0
            width += speed / RATE_HZ
            squeeze = np.clip((t - self.contact_at) / (self.stop_at - self.contact_at), 0, 1)
            squeeze *= 1.0 - np.clip((t - self.open_at) / 0.2, 0, 1)
            left = BASE_PA + squeeze * self.rise_pa + rng.normal(0, self.noise_pa)
            right = BASE_PA + squeeze * right_rise + rng.normal(0, self.noise_pa)
            yield t, left, right, speed, width


def run(monitor: GraspMonitor, grasp: Grasp, start_secs: float = 0.0):
    """Feed a grasp; return [(t, event)] and [(t, stable)] per sample."""
    events, states = [], []
    for t, left, right, speed, width in grasp.samples():
        stamp = int((start_secs + t) * 1e9)
        for status in (
            monitor.update_pressure("left", left, stamp),
            monitor.update_pressure("right", right, stamp),
            monitor.update_gripper(speed, width, stamp),
        ):
            if status.event:
                events.append((t, status.event))
        states.append((t, monitor.stable))
    return events, states


def test_stable_only_after_contact_and_dwell_then_released_on_opening():
    params = GraspParams(dwell_secs=0.3)
    events, states = run(GraspMonitor(params), Grasp())
    assert [e for _, e in events] == ["stable", "released"]
    (t_stable, _), (t_released, _) = events
    # Fingers stop at 1.0 s; the dwell is 0.3 s.
    assert 1.3 <= t_stable <= 1.35
    assert all(not s for t, s in states if t < 1.3)
    # Opening starts at 3.0 s at 20 mm/s: 2 mm of opening ends the grasp after 0.1 s,
    # while the bubbles are still pressed.
    assert 3.09 <= t_released <= 3.12


def test_no_flicker_on_noisy_pressure():
    params = GraspParams(contact_rise_pa=30.0, release_rise_pa=15.0)
    for seed in range(5):
        events, _ = run(GraspMonitor(params), Grasp(noise_pa=4.0, seed=seed))
        assert [e for _, e in events] == ["stable", "released"], seed


def test_hysteresis_holds_a_grasp_near_the_threshold():
    # The squeeze holds right at the contact threshold, with noise: contact starts once and
    # the release threshold is far below the noise, so the grasp does not flicker.
    params = GraspParams(contact_rise_pa=30.0, release_rise_pa=15.0, filter_secs=0.0)
    grasp = Grasp(rise_pa=32.0, noise_pa=3.0, seed=7)
    events, _ = run(GraspMonitor(params), grasp)
    assert [e for _, e in events] == ["stable", "released"]


def test_one_bubble_in_contact_is_not_a_grasp():
    events, states = run(GraspMonitor(), Grasp(right_rise_pa=5.0))
    assert events == [] and not any(s for _, s in states)


def test_moving_fingers_are_not_stable():
    # The pressure rises while the fingers keep closing until 2.5 s: stable only after.
    events, _ = run(GraspMonitor(GraspParams(dwell_secs=0.2)), Grasp(stop_at=2.5))
    assert events[0][1] == "stable" and events[0][0] >= 2.7


def test_slow_baseline_drift_is_not_contact():
    monitor = GraspMonitor(GraspParams(baseline_secs=1.0))
    for i in range(3000):  # 30 s, the pressure drifts up by 60 Pa
        stamp = int(i / RATE_HZ * 1e9)
        pressure = BASE_PA + 2.0 * i / RATE_HZ
        monitor.update_pressure("left", pressure, stamp)
        monitor.update_pressure("right", pressure, stamp)
        status = monitor.update_gripper(0.0, 0.1, stamp)
        assert not status.stable and not status.contact_left
    assert status.pressure_rise_left_pa < 10.0


def test_fixed_baseline_and_regrasp():
    params = GraspParams(baseline_pa=BASE_PA, dwell_secs=0.1)
    monitor = GraspMonitor(params)
    events, _ = run(monitor, Grasp())
    events2, _ = run(monitor, Grasp(), start_secs=10.0)
    assert [e for _, e in events] == ["stable", "released"]
    assert [e for _, e in events2] == ["stable", "released"]


def test_non_finite_samples_are_safe():
    monitor = GraspMonitor(GraspParams(dwell_secs=0.0))
    monitor.update_pressure("left", BASE_PA, 0)
    monitor.update_pressure("right", BASE_PA, 0)
    status = monitor.update_pressure("left", float("nan"), 1)
    assert np.isfinite(status.pressure_rise_left_pa)
    status = monitor.update_gripper(float("nan"), float("nan"), 2)
    assert not status.stable and np.isfinite(status.finger_speed_m_per_s)


def test_status_reports_rises_and_speed():
    monitor = GraspMonitor(GraspParams(baseline_pa=BASE_PA, filter_secs=0.0))
    monitor.update_pressure("left", BASE_PA + 50.0, 0)
    monitor.update_pressure("right", BASE_PA + 20.0, 0)
    status = monitor.update_gripper(-0.01, 0.06, 0)
    assert status.width_m == 0.06
    assert status.pressure_rise_left_pa == pytest.approx(50.0)
    assert status.pressure_rise_right_pa == pytest.approx(20.0)
    assert status.finger_speed_m_per_s == pytest.approx(0.01)
    assert status.contact_left and not status.contact_right


def test_unknown_sensor_and_bad_params():
    with pytest.raises(ValueError, match="sensor"):
        GraspMonitor().update_pressure("middle", 1.0, 0)
    with pytest.raises(ValueError, match="release_rise_pa"):
        build_params(GraspParams, {"contact_rise_pa": 10.0, "release_rise_pa": 20.0})
    with pytest.raises(ValueError, match="release_opening_m"):
        build_params(GraspParams, {"release_opening_m": 0.0})
    with pytest.raises(ValueError, match="dwell_secs"):
        build_params(GraspParams, {"dwell_secs": -1.0})


def run_scene(path: str, monitor: GraspMonitor, noise_pa: float = 0.0, seed: int = 0):
    """Step a scene's world (no rendering); return [(t, event)] and the snapshots."""
    world = sim.World(sim.load_scene(path))
    rng = np.random.default_rng(seed)
    events, snaps = [], []
    while not world.done:
        snap = world.step()
        snaps.append(snap)
        stamp = sim.stamp_of(snap)
        statuses = [
            monitor.update_pressure(side, snap.pressure_pa[side] + rng.normal(0, noise_pa), stamp)
            for side in ("left", "right")
        ]
        statuses.append(monitor.update_gripper(snap.speed_m_per_s, snap.width_m, stamp))
        events += [(snap.time_secs, s.event) for s in statuses if s.event]
    return events, snaps


@pytest.mark.parametrize("noise_pa", [0.0, 20.0])
def test_simulated_mug_grasp(noise_pa):
    params = GraspParams(dwell_secs=0.3)
    events, snaps = run_scene("scenes/mug_grasp.yaml", GraspMonitor(params), noise_pa, seed=3)
    assert [e for _, e in events] == ["stable", "released"]
    (t_stable, _), (t_released, _) = events
    touched = min(s.time_secs for s in snaps if all(s.in_contact.values()))
    stopped = min(s.time_secs for s in snaps if s.gripper_state == "holding")
    assert t_stable > touched
    assert stopped + 0.3 <= t_stable <= stopped + 0.3 + 0.1
    # The release command opens the jaws; the grasp ends within a frame or two.
    opened = min(
        s.time_secs for s in snaps if s.time_secs > t_stable and s.gripper_state == "moving"
    )
    assert opened <= t_released <= opened + 0.07


def test_simulated_handover_stays_stable_while_the_gripper_resqueezes():
    # A person pulls the mug; the force-controlled jaws close a little as it slips. The
    # grasp (and with it the shear reference) must last until the jaws open.
    events, snaps = run_scene("scenes/mug_handover.yaml", GraspMonitor())
    assert [e for _, e in events] == ["stable", "released"]
    t_stable, t_released = events[0][0], events[1][0]
    widths = [s.width_m for s in snaps if t_stable <= s.time_secs < t_released]
    assert max(widths) - min(widths) > 0.002  # it did move while stable
    release_secs = 2.6  # the scene's release command
    assert release_secs <= t_released <= release_secs + 0.07
