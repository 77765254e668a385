"""Shear direction accuracy against time per frame: Farneback settings, DIS presets, half res.

``python -m bench.shear`` runs every setting on the same simulated sequences and prints
one row per setting; ``--json`` rows carry ``method``, ``setting``,
``dir_err_deg_median``, ``dir_err_deg_p95``, ``mag_err_px_median``,
``ms_per_frame_median`` and more. Timing is on one core (``bench.common.one_core``):
``ms_per_frame_median`` is the thread's CPU time per frame on the first sequence, the
least of ``TIMING_REPEATS`` passes per frame (robust to other processes sharing the
machine); ``wall_ms_per_frame_median`` is the wall time over the scoring pass; both cover
:meth:`perception.shear.ShearTracker.update` (mask, stretch, flow, summary, mm and
torsion) for one bubble, not the rendering.

Sequences (the simulator, ``sim``; the same for every setting, both bubbles): a mug held
at its grasp pose in ``scenes/mug_grasp.yaml`` and moved in the hand, rendered with the
``shear`` and ``dot_pattern`` effects, as ramps of frames from rest (shear builds up
over frames in a grasp; warm starts use that): pure translations along the tool's y and
z in 8 directions, twists about the grasp axis, mixtures of both; and the pull of
``scenes/mug_handover.yaml`` from the moment the grasp monitor reports a stable grasp
(the reference) to the release.

Errors: ``dir_err_deg`` is the paper's direction (the normalized summed flow, in the
image) against the true mean image motion of the material over the same pixels, scored
where that is at least ``DIR_MIN_TRUTH_PX``; ``dir_err_mm_deg`` is the angle between
the estimated ``shear_m`` (tool y, z; beyond the paper) and the true mean material
shift, scored where that is at least ``DIR_MIN_TRUTH_M``. An undefined direction where
one is scored counts as 180 degrees. The true motion follows the material (see
:func:`sim.material_flow.truth`). ``mag_err_px`` compares the mean shear in pixels with the true mean
image motion; ``torsion_err_deg`` is scored on twisted frames.

Target: median direction error < 2 deg and 95th percentile < 5 deg at
>= 300 frames/s per bubble on one core.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import sim
from bench.common import (
    Row,
    label_points,
    main,
    median,
    one_core,
    percentile,
    plain_log_ticks,
    progress,
)
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from messages.types import ToFImage
from perception.grasp import GraspMonitor
from perception.shear import (
    DisParams,
    FarnebackParams,
    ShearParams,
    ShearTracker,
    membrane_mask,
    tool_basis,
)
from sim.material_flow import SimGrasp, truth

DIR_MIN_TRUTH_M = 0.25e-3
DIR_MIN_TRUTH_PX = 1.0
RAMP_STEP_M = 0.5e-3
TIMING_REPEATS = 3
HANDOVER_SCENE = "scenes/mug_handover.yaml"


@dataclass(frozen=True)
class Frame:
    """One bubble's frame and its ground truth, against the sequence's reference.

    ``truth_px`` is the mean over the reference mask of the true image motion of the
    membrane material (its shift back-projected from the noise-free reference range);
    ``truth_m`` the mean material shift in the tool's (y, z) plane (metres), over the same
    pixels;
    ``torsion_rad`` the least-squares rotation of that shift field about tool x (the
    estimator's definition), which is smaller than the object's twist because the
    membrane outside the contact does not turn.
    """

    image: ToFImage
    truth_px: np.ndarray
    truth_m: np.ndarray
    torsion_rad: float
    sequence: str


@dataclass(frozen=True)
class Sequence:
    """Frames of one bubble against one reference image."""

    name: str
    sensor: str
    reference: ToFImage
    frames: list[Frame]


def ramps(quick: bool) -> list[tuple[str, list[tuple[tuple[float, float], float]]]]:
    """In-hand motions as ramps of frames (shift in metres along tool y, z; twist rad).

    Shear builds up over frames in a real grasp, so every motion is a ramp from rest,
    sampled at ``RAMP_STEP_M`` (about 1.7 px per frame here: a 15 mm/s pull at 30 fps).
    """
    steps = 4 if quick else 8
    out: list[tuple[str, list[tuple[tuple[float, float], float]]]] = []
    for k in range(0, 8, 2 if quick else 1):
        angle = k * math.pi / 4
        unit = (math.cos(angle), math.sin(angle))
        out.append(
            (
                "translate",
                [
                    ((RAMP_STEP_M * i * unit[0], RAMP_STEP_M * i * unit[1]), 0.0)
                    for i in range(1, steps + 1)
                ],
            )
        )
    for sign in (1.0, -1.0):
        out.append(
            ("twist", [((0.0, 0.0), sign * math.radians(1.0 * i)) for i in range(1, steps - 1)])
        )
    for k in range(0, 8, 4 if quick else 2):
        angle = k * math.pi / 4 + 0.3
        unit = (math.cos(angle), math.sin(angle))
        out.append(
            (
                "mixture",
                [
                    ((0.4e-3 * i * unit[0], 0.4e-3 * i * unit[1]), math.radians(0.6 * i))
                    for i in range(1, steps // 2 + 2)
                ],
            )
        )
    return out


def grasp_sequences(quick: bool) -> list[Sequence]:
    """Ramps of translations in 8 directions, twists and mixtures of a held mug."""
    grasp = SimGrasp()
    reference = grasp.instant(index=0)
    masks = {s: scored_mask(reference.images[s]) for s in SIDES}
    out: list[Sequence] = []
    index = 0
    for name, moves in ramps(quick):
        frames: dict[str, list[Frame]] = {s: [] for s in SIDES}
        for shift, twist in moves:
            index += 1
            current = grasp.instant(shift, twist, index)
            for sensor in SIDES:
                px, metres, torsion = truth(
                    grasp.geometry, grasp.camera, reference, current, sensor, masks[sensor]
                )
                frames[sensor].append(
                    Frame(current.images[sensor], px, metres, torsion if twist else 0.0, name)
                )
        out += [Sequence(name, s, reference.images[s], frames[s]) for s in SIDES]
    return out


def handover_sequences(quick: bool) -> list[Sequence]:
    """The handover scene: reference at the grasp monitor's stable event, then the pull.

    Frames run from the reference to the release command (every 3rd frame with
    ``quick``); the truth is against the reference frame.
    """
    scene = sim.load_scene(HANDOVER_SCENE)
    simulator = sim.Simulator(scene)
    geometry = scene.gripper_geometry()
    camera = scene.camera.intrinsics()
    monitor = GraspMonitor()
    release_secs = min(
        (c.t_secs for c in scene.gripper.commands if c.command == "release"),
        default=scene.duration_secs,
    )
    reference: sim.Instant | None = None
    frames: dict[str, list[Frame]] = {s: [] for s in SIDES}
    step = 3 if quick else 1
    while not simulator.world.done:
        snap = simulator.world.step()
        if snap.time_secs >= release_secs:
            break
        stamp = sim.stamp_of(snap)
        for sensor in SIDES:
            monitor.update_pressure(sensor, snap.pressure_pa[sensor], stamp)
        status = monitor.update_gripper(snap.speed_m_per_s, snap.width_m, stamp)
        if reference is None:
            if status.stable:
                reference = simulator.render_snapshot(snap)
            continue
        if snap.frame_index % step:
            continue
        current = simulator.render_snapshot(snap)
        for sensor in SIDES:
            mask = scored_mask(reference.images[sensor])
            px, metres, _ = truth(geometry, camera, reference, current, sensor, mask)
            frames[sensor].append(Frame(current.images[sensor], px, metres, 0.0, "handover"))
    if reference is None:
        raise RuntimeError(f"{HANDOVER_SCENE}: the grasp monitor never reported a stable grasp")
    return [
        Sequence("handover", sensor, reference.images[sensor], frames[sensor]) for sensor in SIDES
    ]


def sequences(quick: bool) -> list[Sequence]:
    """Every scored sequence, identical for every setting."""
    return grasp_sequences(quick) + handover_sequences(quick)


def settings(quick: bool) -> list[tuple[str, ShearParams]]:
    """The sweep: (setting name, parameters). "half" / "0.6x" = input scaled by 0.5 / 0.6;
    "warm" = each frame's flow starts from the previous frame's (same reference)."""
    fb, dis = FarnebackParams, DisParams
    out = [
        ("fb L3 w15 (OpenCV sample)", ShearParams(farneback=fb())),
        ("fb L3 w45 (facts)", ShearParams(farneback=fb(winsize=45))),
        ("fb L3 w31 p7", ShearParams(farneback=fb(winsize=31, poly_n=7, poly_sigma=1.5))),
        ("warm fb L3 w15", ShearParams(warm_start=True, farneback=fb())),
        ("half fb L3 w15", ShearParams(scale=0.5, farneback=fb())),
        ("half fb L3 w15 p7", ShearParams(scale=0.5, farneback=fb(poly_n=7, poly_sigma=1.5))),
        ("warm half fb L3 w15", ShearParams(scale=0.5, warm_start=True, farneback=fb())),
        (
            "warm half fb L3 w15 p7",
            ShearParams(scale=0.5, warm_start=True, farneback=fb(poly_n=7, poly_sigma=1.5)),
        ),
        ("warm 0.6x fb L3 w15", ShearParams(scale=0.6, warm_start=True, farneback=fb())),
        (
            "warm 0.6x fb L3 w15 p7",
            ShearParams(scale=0.6, warm_start=True, farneback=fb(poly_n=7, poly_sigma=1.5)),
        ),
        (
            "warm half fb L1 w9",
            ShearParams(scale=0.5, warm_start=True, farneback=fb(levels=1, winsize=9)),
        ),
        ("dis ultrafast", ShearParams(method="dis", dis=dis(preset="ultrafast"))),
        ("dis fast", ShearParams(method="dis", dis=dis(preset="fast"))),
        ("dis medium", ShearParams(method="dis", dis=dis(preset="medium"))),
        ("warm dis fast", ShearParams(method="dis", warm_start=True, dis=dis(preset="fast"))),
        ("half dis fast", ShearParams(method="dis", scale=0.5, dis=dis(preset="fast"))),
        ("half dis medium", ShearParams(method="dis", scale=0.5, dis=dis(preset="medium"))),
        (
            "warm half dis ultrafast",
            ShearParams(method="dis", scale=0.5, warm_start=True, dis=dis(preset="ultrafast")),
        ),
        (
            "warm half dis medium",
            ShearParams(method="dis", scale=0.5, warm_start=True, dis=dis(preset="medium")),
        ),
    ]
    if quick:
        keep = {"fb L3 w15 (OpenCV sample)", "warm half fb L3 w15 p7", "dis fast"}
        out = [s for s in out if s[0] in keep]
    return out


def scored_mask(reference: ToFImage) -> np.ndarray:
    """The reference pixels the truth is scored over: the estimator's default mask."""
    return membrane_mask(reference.ir, reference.depth_m, ShearParams())


def angle_error_deg(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Unsigned angle between two 2D vectors, degrees in [0, 180]."""
    diff = math.atan2(estimate[1], estimate[0]) - math.atan2(truth[1], truth[0])
    return abs(math.degrees((diff + math.pi) % (2 * math.pi) - math.pi))


def evaluate(name: str, params: ShearParams, sequences: list[Sequence]) -> Row:
    """One row: errors and time per frame of one setting over every sequence."""
    dir_err_mm, dir_err_px, mag_err, mm_err, torsion_err = [], [], [], [], []
    dir_err_family: dict[str, list[float]] = {"in_hand": [], "handover": []}
    cpu, wall, undefined = [], [], 0
    for seq in sequences:
        tracker = ShearTracker(params)
        ref = seq.reference
        basis = tool_basis(ref.tool_from_sensor)
        tracker.set_reference(ref.ir, ref.depth_m, PinholeCamera.from_frame(ref), basis)
        tracker.update(ref.ir, ref.depth_m)  # warm caches and allocations
        for frame in seq.frames:
            image = frame.image
            start_wall, start_cpu = time.perf_counter_ns(), time.thread_time_ns()
            result = tracker.update(image.ir, image.depth_m)
            cpu.append((time.thread_time_ns() - start_cpu) * 1e-6)
            wall.append((time.perf_counter_ns() - start_wall) * 1e-6)
            mag_err.append(abs(result.magnitude_px - float(np.hypot(*frame.truth_px))))
            mm_err.append(float(np.hypot(*(result.shear_m - frame.truth_m))) * 1000.0)
            # An undefined direction where one exists is a miss (180 degrees).
            if float(np.hypot(*frame.truth_m)) >= DIR_MIN_TRUTH_M:
                defined = result.direction_defined and result.metric_defined
                undefined += not defined
                dir_err_mm.append(
                    angle_error_deg(result.shear_m, frame.truth_m) if defined else 180.0
                )
            if float(np.hypot(*frame.truth_px)) >= DIR_MIN_TRUTH_PX:
                error = (
                    angle_error_deg(result.direction, frame.truth_px)
                    if result.direction_defined
                    else 180.0
                )
                dir_err_px.append(error)
                family = "handover" if seq.name == "handover" else "in_hand"
                dir_err_family[family].append(error)
            if frame.torsion_rad != 0.0:
                torsion_err.append(abs(math.degrees(result.torsion_rad - frame.torsion_rad)))
    ms = timing_ms(params, sequences[0])
    return {
        "method": params.method,
        "setting": name,
        "scale": params.scale,
        "warm_start": params.warm_start,
        "frames": len(cpu),
        "dir_err_deg_median": median(dir_err_px),
        "dir_err_deg_p95": percentile(dir_err_px, 95),
        "dir_err_deg_p95_in_hand": percentile(dir_err_family["in_hand"], 95),
        "dir_err_deg_p95_handover": percentile(dir_err_family["handover"], 95),
        "dir_err_mm_deg_median": median(dir_err_mm),
        "dir_err_mm_deg_p95": percentile(dir_err_mm, 95),
        "dir_undefined": undefined,
        "mag_err_px_median": median(mag_err),
        "mag_err_px_p95": percentile(mag_err, 95),
        "shear_err_mm_median": median(mm_err),
        "torsion_err_deg_median": median(torsion_err),
        "ms_per_frame_median": ms,
        "wall_ms_per_frame_median": median(wall),
        "cpu_ms_per_frame_scoring_pass": median(cpu),
        "fps_one_core": 1000.0 / ms if ms > 0 else float("inf"),
    }


def timing_ms(params: ShearParams, sequence: Sequence, repeats: int = TIMING_REPEATS) -> float:
    """Median over one sequence's frames of the least CPU time of ``repeats`` passes.

    The machine is shared: the least of a few identical passes (a fresh tracker each,
    so warm starts see the same history) filters out time lost to other processes.
    """
    best = [math.inf] * len(sequence.frames)
    ref = sequence.reference
    for _ in range(repeats):
        tracker = ShearTracker(params)
        tracker.set_reference(
            ref.ir,
            ref.depth_m,
            PinholeCamera.from_frame(ref),
            tool_basis(ref.tool_from_sensor),
        )
        tracker.update(ref.ir, ref.depth_m)
        for i, frame in enumerate(sequence.frames):
            start = time.thread_time_ns()
            tracker.update(frame.image.ir, frame.image.depth_m)
            best[i] = min(best[i], (time.thread_time_ns() - start) * 1e-6)
    return median(best)


def run(quick: bool) -> list[Row]:
    """Every setting on the same sequences."""
    one_core()
    seqs = sequences(quick)
    sweep = progress(settings(quick), "bench.shear", label=lambda point: point[0])
    return [evaluate(name, params, seqs) for name, params in sweep]


def plot(rows: list[Row], path: Path) -> None:
    """Direction error (median and p95, log scale) against time per frame; numbered points,
    the settings listed beside."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharex=True)
    for ax, key, target in (
        (axes[0], "dir_err_deg_median", 2.0),
        (axes[1], "dir_err_deg_p95", 5.0),
    ):
        for row in rows:
            x, y = row["ms_per_frame_median"], max(row[key], 0.01)
            color = "tab:blue" if row["method"] == "farneback" else "tab:orange"
            marker = "o" if row["warm_start"] else "s"
            face = color if row["scale"] < 1.0 else "none"
            ax.scatter([x], [y], marker=marker, edgecolors=color, facecolors=face, s=40)
        ax.axvline(1000.0 / 300.0, color="grey", ls="--", lw=1)
        ax.axhline(target, color="grey", ls=":", lw=1)
        plain_log_ticks(ax, "xy")
        ax.set_xlabel("ms per frame (median, one core)")
        ax.set_ylabel(f"{key} (deg)")
        ax.set_title(f"{key}: target {target:g} deg, 300 frames/s (dashed)", fontsize=9)
    legend = "\n".join(f"{i}: {row['setting']}" for i, row in enumerate(rows, start=1))
    fig.text(0.80, 0.5, legend, fontsize=7, va="center", family="monospace")
    fig.suptitle(
        "Shear direction error vs time (blue Farneback, orange DIS; circle warm start, "
        "square cold; filled: reduced resolution)",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 0.79, 0.95))
    numbers = [str(i) for i in range(1, len(rows) + 1)]
    for ax, key in zip(axes, ("dir_err_deg_median", "dir_err_deg_p95"), strict=True):
        points = [(r["ms_per_frame_median"], max(r[key], 0.01)) for r in rows]
        label_points(ax, points, numbers)  # after the layout: placed clear of each other
    fig.savefig(path, dpi=120)
    plt.close(fig)


COLUMNS = [
    "setting",
    "dir_err_deg_median",
    "dir_err_deg_p95",
    "dir_err_mm_deg_median",
    "dir_err_mm_deg_p95",
    "dir_undefined",
    "mag_err_px_median",
    "shear_err_mm_median",
    "torsion_err_deg_median",
    "ms_per_frame_median",
    "fps_one_core",
]

if __name__ == "__main__":
    main("shear", run, columns=COLUMNS, plot=plot)
