"""The calibration a lab runs once per rig and after a bubble swap, step by step.

:func:`calibrate` drives the rig's own devices (passed in, already connected: the
pressure sensors, the cameras and the gripper client of ``devices/``) and asks the
:class:`Lab` for what needs hands:

1. **pressure zero**: the bubbles open to the air; each sensor's mean reading is its
   zero, with the standard error of the mean and the sensor's noise;
2. **free bubble**: inflated again, the gripper open and nothing touching: each camera's
   mean depth (the membrane at rest), its per-pixel noise and invalid fraction;
3. **intrinsics**: the camera's own lens parameters, as its SDK reports them;
4. **mount**: the known cylinder held at several poses, grasped at several forces (so
   openings); each grasp's contact points (pixels pushed in by more than
   ``min_indent_m`` from the free membrane) with the measured opening, and the free
   membrane, go to :func:`perception.calibration.mount.solve_mounts`.

The result is a :class:`~perception.calibration.rigfile.RigCalibration` (rig, serials,
date, each value with its uncertainty). The computations here take arrays, so they are
tested without devices.
"""

from __future__ import annotations

import math
import queue
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from perception.calibration.mount import Grasp, MountSolution, solve_mounts
from perception.calibration.rigfile import (
    CameraCalibration,
    PressureCalibration,
    RigCalibration,
    now_text,
)


class Lab(Protocol):
    """What needs hands: a person at the rig, or the emulated lab (``sim.emulated_lab``)."""

    def vent(self, vented: bool) -> None: ...

    def place(self, tool_from_object: np.ndarray | None) -> None: ...


@dataclass(frozen=True)
class Plan:
    """How much to measure: readings for the zero, frames per step, the grasps."""

    radius_m: float
    poses: Sequence[tuple[np.ndarray | None, float]]  # (pose to tell the lab, force N)
    zero_readings: int = 200
    free_frames: int = 20
    grasp_frames: int = 4
    min_indent_m: float = 0.003
    points_per_grasp: int = 600
    free_points: int = 1500
    seed: int = 0
    motion_timeout_secs: float = 30.0


def pressure_zero(readings_pa: Sequence[float], resolution_pa: float) -> tuple[float, float, float]:
    """``(zero, its uncertainty, noise)`` in pascals from readings at ambient pressure: the
    mean, the standard error combined with a uniform quantization step, the spread."""
    values = np.asarray(readings_pa, float)
    if values.size < 2:
        raise ValueError("pressure zero: at least 2 readings needed")
    noise = float(values.std(ddof=1))
    sigma = math.hypot(noise / math.sqrt(values.size), resolution_pa / math.sqrt(12 * values.size))
    return float(values.mean()), sigma, noise


def reference_stats(depths: Sequence[np.ndarray]) -> tuple[np.ndarray, dict[str, float]]:
    """The free membrane's mean depth and its statistics over frames of a still, free bubble:
    ``noise_m`` (median per-pixel standard deviation), ``invalid_fraction`` (pixels NaN in
    more than half the frames), ``frames``."""
    stack = np.stack([np.asarray(d, np.float32) for d in depths])
    valid = np.isfinite(stack)
    mean = nanmean(stack)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a pixel NaN in every frame
        std = np.nanstd(stack, axis=0)
    mostly = valid.mean(axis=0) > 0.5
    mean = np.where(mostly, mean, np.nan).astype(np.float32)
    noise = float(np.nanmedian(std[mostly])) if mostly.any() else float("nan")
    return mean, {
        "noise_m": noise,
        "invalid_fraction": float(1.0 - mostly.mean()),
        "frames": float(len(depths)),
    }


def nanmean(stack: np.ndarray) -> np.ndarray:
    """The per-pixel mean over frames of the valid values (NaN where none is)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a pixel NaN in every frame
        mean: np.ndarray = np.nanmean(stack, axis=0)
        return mean


def _subsample(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return points if len(points) <= n else points[rng.choice(len(points), n, replace=False)]


def free_points(
    mean_depth: np.ndarray, camera: PinholeCamera, n: int, rng: np.random.Generator
) -> np.ndarray:
    """Points of the free membrane in the sensor frame (N, 3), at most ``n``."""
    pts = camera.depth_to_points(mean_depth).reshape(-1, 3)
    return _subsample(pts[np.isfinite(pts).all(axis=1)].astype(np.float64), n, rng)


def contact_points(
    depth: np.ndarray,
    free_depth: np.ndarray,
    camera: PinholeCamera,
    *,
    min_indent_m: float,
    n: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points pushed in by at least ``min_indent_m`` from the free membrane (sensor frame)."""
    with np.errstate(invalid="ignore"):
        pushed = (free_depth - depth) >= min_indent_m
    pts = camera.depth_to_points(np.where(pushed, depth, np.nan)).reshape(-1, 3)
    return _subsample(pts[np.isfinite(pts).all(axis=1)].astype(np.float64), n, rng)


def fresh_depths(
    cameras: Mapping[str, Any], count: int, *, timeout_secs: float = 10.0
) -> dict[str, list[np.ndarray]]:
    """``count`` depth images from each camera's frame queue (``camera.frames``), taken
    from now on, from all cameras at once: what was queued is dropped, and so is each
    camera's next frame (it may have been exposed before now)."""
    after = {side: _drain(cam.frames) for side, cam in cameras.items()}
    skip = dict.fromkeys(cameras, 1)
    out: dict[str, list[np.ndarray]] = {side: [] for side in cameras}
    end = time.monotonic() + timeout_secs
    while any(len(d) < count for d in out.values()):
        if time.monotonic() > end:
            got = ", ".join(f"{side} {len(d)}" for side, d in out.items())
            raise TimeoutError(f"calibration: {got} of {count} frames in {timeout_secs} s")
        waiting = False
        for side, cam in cameras.items():
            if len(out[side]) >= count:
                continue
            try:
                frame = cam.frames.get_nowait()
            except queue.Empty:
                waiting = True
                continue
            if frame.stamp_nanos <= after[side]:
                continue
            if skip[side]:
                skip[side] -= 1
                continue
            out[side].append(frame.depth_m)
        if waiting:
            time.sleep(0.005)
    return out


def _drain(frames: queue.Queue[Any]) -> int:
    """Empty the queue; the newest stamp it held (0 when empty)."""
    newest = 0
    while True:
        try:
            newest = max(newest, frames.get_nowait().stamp_nanos)
        except queue.Empty:
            return newest


def calibrate(
    *,
    rig: str,
    sensors: Mapping[str, Any],
    cameras: Mapping[str, Any],
    gripper: Any,
    lab: Lab,
    plan: Plan,
    resolution_pa: float,
    say: Callable[[str], None] = print,
) -> tuple[RigCalibration, MountSolution]:
    """Run the procedure (module docstring) on connected devices; returns the calibration.

    ``sensors``: per side an ``devices.abp.AbpSensor`` (its ``bridge.device_serial``);
    ``cameras``: per side a connected ``devices.royale.RoyaleCamera``; ``gripper``: a
    connected ``devices.wsg50_client.WSG50Client``.
    """
    rng = np.random.default_rng(plan.seed)
    say("1/4 pressure zero: the bubbles open to the air")
    lab.vent(True)
    time.sleep(0.3)
    pressure: dict[str, PressureCalibration] = {}
    for side in SIDES:
        readings: list[float] = []
        while len(readings) < plan.zero_readings:
            reading = sensors[side].read()
            if reading.status == 0:
                readings.append(reading.pressure_pa)
            time.sleep(0.002)
        zero, sigma, noise = pressure_zero(readings, resolution_pa)
        serial = sensors[side].bridge.device_serial
        pressure[side] = PressureCalibration(serial, zero, sigma, noise)
        say(f"    {side}: zero {zero:+.2f} +- {sigma:.2f} Pa (noise {noise:.2f} Pa, {serial})")
    lab.vent(False)

    say("2/4 free bubble: inflated, gripper open, nothing touching")
    lab.place(None)
    gripper.move(0.11, 0.1).wait(plan.motion_timeout_secs)
    time.sleep(0.3)
    free_depth: dict[str, np.ndarray] = {}
    stats: dict[str, dict[str, float]] = {}
    lenses: dict[str, PinholeCamera] = {}
    free_frames = fresh_depths(cameras, plan.free_frames, timeout_secs=60.0)
    for side in SIDES:
        cam = cameras[side]
        depths = free_frames[side]
        free_depth[side], stats[side] = reference_stats(depths)
        k = cam.intrinsics
        h, w = depths[0].shape
        lenses[side] = PinholeCamera(
            width_px=w, height_px=h, fx_px=k.fx_px, fy_px=k.fy_px, cx_px=k.cx_px, cy_px=k.cy_px
        )
        say(
            f"    {side}: noise {stats[side]['noise_m'] * 1000:.2f} mm, invalid"
            f" {stats[side]['invalid_fraction'] * 100:.1f} % ({cam.camera_id})"
        )
    say(
        "3/4 intrinsics from the cameras' SDK: "
        + ", ".join(
            f"{s} fx {lenses[s].fx_px:.1f} fy {lenses[s].fy_px:.1f} cx {lenses[s].cx_px:.1f}"
            f" cy {lenses[s].cy_px:.1f}"
            for s in SIDES
        )
    )

    say(
        f"4/4 mount: {len(plan.poses)} grasps of the cylinder (radius {plan.radius_m * 1000:.1f} mm)"
    )
    grasps: list[Grasp] = []
    for k, (pose, force_n) in enumerate(plan.poses):
        lab.place(pose)
        gripper.set_force_limit(force_n)
        gripper.grasp(0.0, 0.1).wait(plan.motion_timeout_secs)
        time.sleep(0.2)
        width = gripper.opening_m()
        points = {}
        seen = fresh_depths(cameras, plan.grasp_frames, timeout_secs=30.0)
        for side in SIDES:
            points[side] = contact_points(
                nanmean(np.stack(seen[side])),
                free_depth[side],
                lenses[side],
                min_indent_m=plan.min_indent_m,
                n=plan.points_per_grasp,
                rng=rng,
            )
        grasps.append(Grasp(width, points))
        say(
            f"    grasp {k + 1}: {force_n:.0f} N, opening {width * 1000:.1f} mm, contact points"
            f" {len(points['left'])}/{len(points['right'])}"
        )
        gripper.release(0.11, 0.1).wait(plan.motion_timeout_secs)
    lab.place(None)
    free = {s: free_points(free_depth[s], lenses[s], plan.free_points, rng) for s in SIDES}
    solution = solve_mounts(free, grasps, plan.radius_m)
    cams = {}
    for side in SIDES:
        fit = solution.mounts[side]
        cam = cameras[side]
        cams[side] = CameraCalibration(
            camera_id=cam.camera_id,
            finger_from_sensor=fit.finger_from_sensor,
            rotation_sigma_deg=fit.rotation_sigma_deg,
            translation_sigma_mm=fit.translation_sigma_mm,
            intrinsics={
                "fx": lenses[side].fx_px,
                "fy": lenses[side].fy_px,
                "cx": lenses[side].cx_px,
                "cy": lenses[side].cy_px,
            },  # fmt: skip
            reference=stats[side],
        )
        say(
            f"    {side}: mount corrected by {fit.correction_deg:.2f} deg, {fit.correction_mm:.2f}"
            f" mm (+- {fit.rotation_sigma_deg:.3f} deg, {fit.translation_sigma_mm:.3f} mm)"
        )
    say(
        f"    fit rms: grasps {solution.grasp_rms_mm:.2f} mm, free membrane"
        f" {solution.membrane_rms_mm:.2f} mm"
    )
    return RigCalibration(rig=rig, date=now_text(), cameras=cams, pressure=pressure), solution
