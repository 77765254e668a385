"""Simulator frame rate by effect set, and membrane accuracy against time.

Two sweeps in one table:

* ``effects``: frames per second for both bubbles (one world step plus both cameras'
  renders, i.e. ``sim.Simulator.step``) from the minimal set (membrane, depth) adding
  one effect per row up to all of them; ``effect_ms`` is what the added effect costs.
  Frames come from the mug grasp scene while the held mug is twisted and pushed (in
  contact, moving every frame).
* ``membrane``: the membrane renderer's knobs (``resolution_divisor``, ``march_steps``)
  against the depth error in the contact patch, relative to a converged full-resolution
  reference (divisor 1, 6 Newton steps), minimal effects.

    python -m bench.sim [--quick] [--json] [--plot PATH]

Timings run on one core (``bench.common.one_core``); ``ms_per_frame`` and the frame
rates are CPU time of this single-threaded process (the machine is shared, so wall time,
``wall_ms_per_frame``, includes waiting for a core). Target: all effects at
45 fps or more for both bubbles; the minimal set several times faster.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from bench.common import Row, main, median, one_core, progress

SCENE = "scenes/mug_grasp.yaml"
# The in-hand twist and push of the mug grasp: the mug moves every frame, so no frame
# reuses the last one's membrane (a still, held object would).
HOLD_START_SECS = 1.6
STEPS = [
    ("membrane", "depth"),
    ("ir",),
    ("tof_noise",),
    ("dot_pattern",),
    ("shear",),
    ("pressure",),
    ("gripper",),
    ("ground_truth",),
]


def _clock(fn: Any) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one call: the machine is shared, so the CPU time
    of this single-threaded process is the one-core cost; wall time is reported too."""
    c0, w0 = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c0, time.perf_counter() - w0


def _time_steps(scene: Any, frames: int, repeats: int) -> tuple[float, float]:
    """Median (CPU, wall) seconds per ``Simulator.step`` over moving held frames (best
    of ``repeats``)."""
    import sim

    best = (float("inf"), float("inf"))
    for _ in range(repeats):
        simulator = sim.Simulator(scene)
        simulator.world.run_to(HOLD_START_SECS)
        simulator.step()  # builds the texture and warms caches outside the timing
        times = [_clock(simulator.step) for _ in range(frames)]
        run = (median([t[0] for t in times]), median([t[1] for t in times]))
        best = min(best, run)
    return best


def _effect_rows(quick: bool) -> list[Row]:
    import sim

    base = sim.load_scene(SCENE)
    frames, repeats = (8, 1) if quick else (40, 3)  # 40 frames: t = 1.63 .. 2.97 s
    rows: list[Row] = []
    listed: list[str] = []
    previous_ms = 0.0
    for added in progress(STEPS, "bench.sim", label=lambda a: f"effects +{'+'.join(a)}"):
        listed += list(added)
        scene = base.with_effects(tuple(listed))
        secs, wall = _time_steps(scene, frames, repeats)
        ms = secs * 1000.0
        rows.append(
            {
                "sweep": "effects",
                "effects": "+".join(listed) if len(listed) <= 2 else f"+{added[0]}",
                "effect_count": len(listed),
                "ms_per_frame": ms,
                "wall_ms_per_frame": wall * 1000.0,
                "fps_both_bubbles": 1.0 / secs,
                "effect_ms": ms - previous_ms if previous_ms else ms,
                "resolution_divisor": scene.membrane.resolution_divisor,
                "march_steps": scene.membrane.march_steps,
            }
        )
        previous_ms = ms
    return rows


def _membrane_rows(quick: bool) -> list[Row]:
    import numpy as np

    import sim

    base = sim.load_scene(SCENE).with_effects(("membrane", "depth"))
    times_s = [HOLD_START_SECS + 0.1 * i for i in range(3 if quick else 12)]
    snaps = []
    world = sim.World(base)
    for t in times_s:
        snaps.append(world.run_to(t))

    def depths(scene: Any) -> tuple[list[dict[str, Any]], float]:
        renderers = {s: sim.BubbleRenderer(scene, s) for s in ("left", "right")}
        out, times = [], []
        for snap in snaps:
            frames: dict[str, Any] = {}

            def both(snap: Any = snap, frames: dict[str, Any] = frames) -> None:
                frames.update({s: r.render(snap) for s, r in renderers.items()})

            times.append(_clock(both))
            out.append(frames)
        return out, median([t[0] for t in times])

    ref_scene = dataclasses.replace(
        base, membrane=dataclasses.replace(base.membrane, resolution_divisor=1, march_steps=6)
    )
    reference, _ = depths(ref_scene)
    rows: list[Row] = []
    grid = [(divisor, steps) for divisor in (1, 2, 4) for steps in (1, 2, 3)]
    label = "membrane divisor {0[0]}, {0[1]} march steps".format
    for divisor, steps in progress(grid, "bench.sim", label=label):
        scene = dataclasses.replace(
            base,
            membrane=dataclasses.replace(
                base.membrane, resolution_divisor=divisor, march_steps=steps
            ),
        )
        got, secs = depths(scene)
        errors = []
        for ref, cur in zip(reference, got, strict=True):
            for side in ("left", "right"):
                mask = ref[side].arrays["contact"]
                diff = cur[side].arrays["depth_m"][mask] - ref[side].arrays["depth_m"][mask]
                errors.append(diff[np.isfinite(diff)])
        err = np.concatenate(errors) * 1000.0
        rows.append(
            {
                "sweep": "membrane",
                "effects": "membrane+depth",
                "resolution_divisor": divisor,
                "march_steps": steps,
                "ms_per_frame": secs * 1000.0,
                "fps_both_bubbles": 1.0 / secs,
                "depth_rms_mm": float(np.sqrt(np.mean(err**2))),
                "depth_p99_mm": float(np.percentile(np.abs(err), 99)),
            }
        )
    return rows


def run(quick: bool) -> list[Row]:
    one_core()
    return _effect_rows(quick) + _membrane_rows(quick)


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    eff = [r for r in rows if r["sweep"] == "effects"]
    ax1.barh([r["effects"] for r in eff], [r["fps_both_bubbles"] for r in eff])
    ax1.axvline(45, color="r", linestyle="--", label="45 fps target")
    ax1.set_xlabel("frames per second, both bubbles, one core")
    ax1.invert_yaxis()
    ax1.legend()
    mem = [r for r in rows if r["sweep"] == "membrane"]
    for divisor in sorted({r["resolution_divisor"] for r in mem}):
        sub = [r for r in mem if r["resolution_divisor"] == divisor]
        ax2.plot(
            [r["ms_per_frame"] for r in sub],
            [max(r["depth_rms_mm"], 1e-4) for r in sub],
            "o-",
            label=f"divisor {divisor} (steps 1..3)",
        )
    ax2.set_yscale("log")
    ax2.set_xlabel("ms per frame (both bubbles, membrane+depth)")
    ax2.set_ylabel("depth RMS error in contact, mm")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main(
        "sim",
        run,
        columns=[
            "sweep",
            "effects",
            "resolution_divisor",
            "march_steps",
            "ms_per_frame",
            "wall_ms_per_frame",
            "fps_both_bubbles",
            "effect_ms",
            "depth_rms_mm",
            "depth_p99_mm",
        ],
        plot=plot,
    )
