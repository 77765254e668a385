"""Shear direction accuracy against time per frame: Farneback settings, DIS presets, half res.

``python -m bench.shear`` runs every setting on the same simulated sequences and prints
one row per setting; ``--json`` rows carry ``method``, ``setting``,
``dir_err_deg_median``, ``dir_err_deg_p95``, ``mag_err_px_median``,
``ms_per_frame_median`` and more. Timing is on one core (``bench.common.one_core``):
``ms_per_frame_median`` is the thread's CPU time per frame (robust to other processes
sharing the machine), ``wall_ms_per_frame_median`` the wall time; both cover :meth:`perception.shear.ShearTracker.update` (mask, stretch, flow, summary,
mm and torsion), not the rendering.

Sequences (the same for every setting): pure translations in 8 directions at several
magnitudes, twists about the image centre, mixtures of both, and a handover pull (a
ramp of shear in one direction). The direction error is scored on frames whose true
mean shear is at least ``DIR_MIN_TRUTH_PX``; the torsion error on frames with a twist.

Target (issue 5): median direction error < 2 deg and 95th percentile < 5 deg at
>= 300 frames/s per bubble on one core.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.common import Row, main, median, one_core, percentile
from geometry.camera import PinholeCamera
from perception.shear import (
    DisParams,
    FarnebackParams,
    ShearParams,
    ShearTracker,
    membrane_mask,
)

DIR_MIN_TRUTH_PX = 0.5


@dataclass(frozen=True)
class Frame:
    """One frame of a sequence and its ground truth (full-resolution pixels)."""

    ir: np.ndarray
    depth_m: np.ndarray
    truth_px: np.ndarray  # mean displacement over the reference mask
    truth_mm: np.ndarray  # same, on the membrane (t1, t2)
    torsion_rad: float
    sequence: str


class DotPlane:
    """A random-dot membrane seen face-on at a fixed depth, warped by a known rigid field.

    A stand-in for the simulator's IR rendering: dots of 1.6-3.2 px diameter, a
    supersampled texture sampled through the inverse of the motion, vignetting, and
    Gaussian amplitude noise. The motion of a dot at pixel ``p`` is
    ``c + R(theta) (p - c) + t - p`` with ``c`` the image centre.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        *,
        depth_m: float = 0.08,
        dots_per_px: float = 1.0 / 40.0,
        noise_ir: float = 20.0,
        depth_noise_m: float = 0.0008,
        seed: int = 0,
        supersample: int = 4,
    ) -> None:
        self.camera = camera
        self.depth_m = depth_m
        self.noise_ir = noise_ir
        self.depth_noise_m = depth_noise_m
        self.rng = np.random.default_rng(seed)
        h, w = camera.shape
        s = supersample
        self.supersample = s
        texture = np.zeros((h * s, w * s), np.float32)
        margin = 20
        count = int((h + 2 * margin) * (w + 2 * margin) * dots_per_px)
        shift = 4  # cv2 drawing with 4 fractional bits
        for _ in range(count):
            x = self.rng.uniform(-margin, w + margin) * s
            y = self.rng.uniform(-margin, h + margin) * s
            r = self.rng.uniform(0.8, 1.6) * s
            centre = (int(x * (1 << shift)), int(y * (1 << shift)))
            cv2.circle(texture, centre, int(r * (1 << shift)), 1.0, -1, cv2.LINE_AA, shift)
        self.texture = cv2.GaussianBlur(texture, (0, 0), s * 0.5)
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        self.xs, self.ys = xs, ys
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        self.centre = (cx, cy)
        self.shading = (1.0 - 0.4 * (((xs - cx) / w) ** 2 + ((ys - cy) / h) ** 2)).astype(
            np.float32
        )

    def field(self, t_px: tuple[float, float], theta_rad: float) -> np.ndarray:
        """The true displacement ``(h, w, 2)`` of the dot at each reference pixel."""
        cx, cy = self.centre
        co, si = math.cos(theta_rad), math.sin(theta_rad)
        rx, ry = self.xs - cx, self.ys - cy
        dx = co * rx - si * ry - rx + t_px[0]
        dy = si * rx + co * ry - ry + t_px[1]
        return np.stack([dx, dy], axis=-1)

    def render(
        self, t_px: tuple[float, float] = (0.0, 0.0), theta_rad: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """IR (uint16) and depth (float32 m, with noise) of the membrane moved by the field."""
        cx, cy = self.centre
        co, si = math.cos(-theta_rad), math.sin(-theta_rad)
        qx, qy = self.xs - cx - t_px[0], self.ys - cy - t_px[1]
        gx = cx + co * qx - si * qy
        gy = cy + si * qx + co * qy
        s = self.supersample
        dots = cv2.remap(self.texture, (gx + 0.5) * s - 0.5, (gy + 0.5) * s - 0.5, cv2.INTER_LINEAR)
        ir = (800.0 + 2000.0 * dots) * self.shading
        ir += self.rng.normal(0.0, self.noise_ir, ir.shape)
        depth = self.depth_m + self.rng.normal(0.0, self.depth_noise_m, ir.shape)
        return (
            np.clip(ir, 0, 65535).astype(np.uint16),
            depth.astype(np.float32),
        )

    def mm_per_px(self) -> np.ndarray:
        """Membrane millimetres per pixel along x and y (face-on plane: depth / focal length)."""
        return self.depth_m * 1000.0 / np.array([self.camera.fx_px, self.camera.fy_px])


def sequences(quick: bool, seed: int = 0) -> tuple[DotPlane, Frame, list[Frame]]:
    """The reference frame and the scored frames, identical for every setting."""
    camera = PinholeCamera.from_fov()
    scene = DotPlane(camera, seed=seed)
    ref_ir, ref_depth = scene.render()
    ref_mask = membrane_mask(ref_ir, ref_depth, ShearParams())
    ref = Frame(ref_ir, ref_depth, np.zeros(2), np.zeros(2), 0.0, "reference")
    frames: list[Frame] = []

    def add(t: tuple[float, float], theta: float, name: str) -> None:
        ir, depth = scene.render(t, theta)
        truth = scene.field(t, theta)[ref_mask].mean(axis=0).astype(np.float64)
        frames.append(Frame(ir, depth, truth, truth * scene.mm_per_px(), theta, name))

    magnitudes = (1.0, 3.0) if quick else (0.5, 1.0, 2.0, 4.0)
    for k in range(8):
        angle = k * math.pi / 4
        for m in magnitudes:
            add((m * math.cos(angle), m * math.sin(angle)), 0.0, "translate")
    for deg in (-4.0, 2.0) if quick else (-4.0, -2.0, -1.0, 1.0, 2.0, 4.0):
        add((0.0, 0.0), math.radians(deg), "twist")
    for k in range(0, 8, 4 if quick else 1):
        angle = k * math.pi / 4 + 0.3
        add((2.0 * math.cos(angle), 2.0 * math.sin(angle)), math.radians(2.0), "mixture")
    pull = math.radians(200.0)
    for i in range(1, 5 if quick else 13):
        m = 0.4 * i
        add((m * math.cos(pull), m * math.sin(pull)), math.radians(0.1 * i), "handover")
    return scene, ref, frames


def settings(quick: bool) -> list[tuple[str, ShearParams]]:
    """The sweep: (setting name, parameters)."""
    fb = FarnebackParams
    out = [
        ("fb L3 w15 (OpenCV sample)", ShearParams(farneback=fb())),
        ("fb L3 w45 (FACTS)", ShearParams(farneback=fb(winsize=45))),
        ("fb L1 w15", ShearParams(farneback=fb(levels=1))),
        ("fb L2 w25", ShearParams(farneback=fb(levels=2, winsize=25))),
        ("half fb L3 w15", ShearParams(scale=0.5, farneback=fb())),
        ("half fb L2 w15", ShearParams(scale=0.5, farneback=fb(levels=2))),
        ("half fb L1 w9", ShearParams(scale=0.5, farneback=fb(levels=1, winsize=9))),
        (
            "half fb L2 w9 it2",
            ShearParams(scale=0.5, farneback=fb(levels=2, winsize=9, iterations=2)),
        ),
        ("dis ultrafast", ShearParams(method="dis", dis=DisParams(preset="ultrafast"))),
        ("dis fast", ShearParams(method="dis", dis=DisParams(preset="fast"))),
        ("dis medium", ShearParams(method="dis", dis=DisParams(preset="medium"))),
        ("half dis fast", ShearParams(method="dis", scale=0.5, dis=DisParams(preset="fast"))),
        ("half dis medium", ShearParams(method="dis", scale=0.5, dis=DisParams(preset="medium"))),
    ]
    if quick:
        keep = {"fb L3 w15 (OpenCV sample)", "half fb L2 w15", "dis fast"}
        out = [s for s in out if s[0] in keep]
    return out


def angle_error_deg(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Unsigned angle between two 2D vectors, degrees in [0, 180]."""
    diff = math.atan2(estimate[1], estimate[0]) - math.atan2(truth[1], truth[0])
    return abs(math.degrees((diff + math.pi) % (2 * math.pi) - math.pi))


def evaluate(
    name: str, params: ShearParams, scene: DotPlane, ref: Frame, frames: list[Frame]
) -> Row:
    """One row: errors and time per frame of one setting over all frames."""
    tracker = ShearTracker(params)
    tracker.set_reference(ref.ir, ref.depth_m, scene.camera)
    tracker.update(frames[0].ir, frames[0].depth_m)  # warm caches and allocations
    dir_err, mag_err, mm_err, torsion_err, cpu, wall, undefined = [], [], [], [], [], [], 0
    for frame in frames:
        start_wall, start_cpu = time.perf_counter_ns(), time.thread_time_ns()
        result = tracker.update(frame.ir, frame.depth_m)
        cpu.append((time.thread_time_ns() - start_cpu) * 1e-6)
        wall.append((time.perf_counter_ns() - start_wall) * 1e-6)
        true_mag = float(np.hypot(*frame.truth_px))
        mag_err.append(abs(result.magnitude_px - true_mag))
        mm_err.append(float(np.hypot(*(result.shear_mm - frame.truth_mm))))
        if true_mag >= DIR_MIN_TRUTH_PX:
            if result.direction_defined:
                dir_err.append(angle_error_deg(result.direction, frame.truth_px))
            else:
                undefined += 1
                dir_err.append(180.0)  # an undefined direction where one exists is a miss
        if frame.torsion_rad != 0.0:
            torsion_err.append(abs(math.degrees(result.torsion_rad - frame.torsion_rad)))
    ms = median(cpu)
    return {
        "method": params.method,
        "setting": name,
        "scale": params.scale,
        "frames": len(frames),
        "dir_err_deg_median": median(dir_err),
        "dir_err_deg_p95": percentile(dir_err, 95),
        "dir_undefined": undefined,
        "mag_err_px_median": median(mag_err),
        "mag_err_px_p95": percentile(mag_err, 95),
        "shear_err_mm_median": median(mm_err),
        "torsion_err_deg_median": median(torsion_err),
        "ms_per_frame_median": ms,
        "wall_ms_per_frame_median": median(wall),
        "fps_one_core": 1000.0 / ms if ms > 0 else float("inf"),
    }


def run(quick: bool) -> list[Row]:
    """Every setting on the same sequences."""
    one_core()
    scene, ref, frames = sequences(quick)
    return [evaluate(name, params, scene, ref, frames) for name, params in settings(quick)]


def plot(rows: list[Row], path: Path) -> None:
    """Direction error (median and p95) against time per frame, one point per setting."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for row in rows:
        x = row["ms_per_frame_median"]
        color = "tab:blue" if row["method"] == "farneback" else "tab:orange"
        ax.plot([x, x], [row["dir_err_deg_median"], row["dir_err_deg_p95"]], color=color, lw=1)
        ax.scatter([x], [row["dir_err_deg_median"]], color=color, s=20)
        ax.annotate(row["setting"], (x, row["dir_err_deg_median"]), fontsize=7)
    ax.axvline(1000.0 / 300.0, color="grey", ls="--", lw=1, label="300 frames/s")
    ax.axhline(2.0, color="grey", ls=":", lw=1, label="2 deg median target")
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (median, one core)")
    ax.set_ylabel("direction error, deg (dot: median, bar to p95)")
    ax.set_title("Shear direction error against time (blue Farneback, orange DIS)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


COLUMNS = [
    "setting",
    "dir_err_deg_median",
    "dir_err_deg_p95",
    "dir_undefined",
    "mag_err_px_median",
    "shear_err_mm_median",
    "torsion_err_deg_median",
    "ms_per_frame_median",
    "fps_one_core",
]

if __name__ == "__main__":
    main("shear", run, columns=COLUMNS, plot=plot)
