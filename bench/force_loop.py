"""The closed-loop sweeps of ``bench.force``: the reflex (a grasp whose load outgrows its
grip, run without and with the slip reflex, on either world) and the handover's release
decision by the shear and the force rules (``world.sim``). ``python -m bench.force``
runs them beside the open-loop sweeps (the wrench's error, the slip detector's onsets);
its docstring says what each row means."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np

import sim
from bench import force_mujoco, tasks
from bench.common import Row, median
from bench.force_data import DEFAULT_SETTING, DROP_M, OBJECTS, SETTINGS, Bubbles, draw, monitor_step
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from perception.force.estimators import Calibration, estimate
from perception.force.reflex import GripReflex, PullWatch, ReflexParams
from perception.force.slip import SlipDetector
from perception.grasp import GraspMonitor
from perception.shear import ShearParams, ShearTracker, tool_basis


def stepped(simulator: sim.Simulator) -> Iterator[tuple[Any, Any, dict]]:
    """Each instant of a closed-loop run to its end: the simulator's instant, the grasp
    monitor's state at it (fed the bubbles' pressures and the jaws) and each bubble's
    contact features."""
    bubbles = Bubbles(SETTINGS[DEFAULT_SETTING])
    monitor = GraspMonitor()
    while not simulator.world.done:
        inst = simulator.step()
        status = monitor_step(monitor, inst.snapshot)
        yield inst, status, bubbles.frame(inst, simulator.scene)


def closed_loop(
    seed: int, duration_secs: float, cal: Calibration, *, reflex: bool, mujoco_mesh_m: float = 0.0
) -> dict:
    """One grasp whose load outgrows its grip, with or without the reflex; on MuJoCo
    (live, a free object) with a ``mujoco_mesh_m`` membrane mesh, else on ``world.sim``."""
    spec = draw(seed, duration_secs=duration_secs, load="fill", bounded=True)
    scene = spec.scene
    simulator = (
        force_mujoco.simulator(scene, mujoco_mesh_m) if mujoco_mesh_m else sim.Simulator(scene)
    )
    detectors = {s: SlipDetector.for_rig(cal) for s in SIDES}
    limit = OBJECTS[spec.object][3]
    grip = GripReflex(ReflexParams(max_force_n=limit), spec.grip_n, cal.friction)
    stable = False
    slides: list[np.ndarray] = []
    for inst, status, feats in stepped(simulator):
        snap = inst.snapshot
        if status.stable and not stable:
            for d in detectors.values():
                d.reference()
        stable = status.stable
        wrenches = {s: estimate(feats[s], s, cal, "physics") for s in SIDES}
        load = float(np.hypot(*sum(w.force_n for w in wrenches.values())[1:]))
        for side in SIDES:
            report = detectors[side].update(feats[side], wrenches[side].force_n, snap.time_secs)
            if reflex and report.onset:
                force = grip.on_slip(snap.time_secs, load)
                if force is not None:
                    simulator.world.command("grasp", width_m=0.0, speed_m_per_s=0.08, force_n=force)
        slides.append(snap.slide_m.copy())
    slide = float(np.linalg.norm(slides[-1]))
    if mujoco_mesh_m:
        # MuJoCo's shell gives under a tangential load (about 0.5 mm per newton): a held
        # object moves centimetres on it. Kept: still touching both bubbles and not
        # sliding out (a slipping patch lets the object accelerate away).
        speed = np.linalg.norm(slides[-1] - slides[-4]) / (3 * scene.frame_period_secs)
        kept = all(snap.in_contact.values()) and speed < force_mujoco.DROP_SPEED_M_PER_S
    else:
        kept = slide < DROP_M
    return {
        "object": spec.object,
        "kept": bool(kept),
        "slide_mm": slide * 1000.0,
        "raises": grip.raises,
        "final_grip_n": grip.force_n,
        "max_grip_n": limit,
    }


def reflex_rows(
    seeds: list[int], duration_secs: float, cal: Calibration, mujoco_mesh_m: float = 0.0
) -> list[Row]:
    """Each seed without the reflex, then with it. The ``on`` row says how many of the
    open loop's drops the reflex kept (``saved``), and of them those it could keep within
    the object's bound (a drop with the grip at the bound is the bound's doing)."""
    rows: list[Row] = []
    runs: dict[bool, list[dict]] = {}
    for reflex in (False, True):
        runs[reflex] = [
            closed_loop(s, duration_secs, cal, reflex=reflex, mujoco_mesh_m=mujoco_mesh_m)
            for s in seeds
        ]
        done = runs[reflex]
        at_bound = [not r["kept"] and r["final_grip_n"] >= r["max_grip_n"] for r in done]
        row: Row = {
            "sweep": "reflex",
            "world": "mujoco" if mujoco_mesh_m else "sim",
            "setting": "on" if reflex else "off",
            "method": "physics",
            "samples": len(done),
            "kept": sum(r["kept"] for r in done),
            "dropped": sum(not r["kept"] for r in done),
            "dropped_at_bound": sum(at_bound),
            "slide_mm_median": median([r["slide_mm"] for r in done]),
            "raises_median": median([float(r["raises"]) for r in done]),
            "objects": ",".join(
                f"{r['object']}:{'kept' if r['kept'] else 'dropped'}"
                + (f"@{r['final_grip_n']:.0f}N" if bound else "")
                for r, bound in zip(done, at_bound, strict=True)
            ),
        }
        if reflex:
            lost = [not r["kept"] for r in runs[False]]
            saved = [a and r["kept"] for a, r in zip(lost, done, strict=True)]
            within = [a and not b for a, b in zip(lost, at_bound, strict=True)]
            row["open_loop_dropped"] = sum(lost)
            row["saved_fraction"] = sum(saved) / sum(lost) if any(lost) else float("nan")
            row["saved_within_bound_fraction"] = (
                sum(saved) / sum(within) if any(within) else float("nan")
            )
        rows.append(row)
    return rows


def handover_runs(seed: int, cal: Calibration) -> dict:
    """Frames from the pull's start to each rule's release, and false releases held still."""
    start = tasks.pull_start_secs(seed)
    base = sim.load_scene("scenes/handover_task.yaml")
    z0 = 0.005
    keys = [(0.0, z0), (start, z0), (start + 1.0, z0 + 0.015), (4.0, z0 + 0.040)]
    pulled = dataclasses.replace(
        base,
        seed=200 + seed,
        trajectory=tuple(sim.scene.Keyframe(t_secs=t, xyz_m=(0.0, 0.0, z)) for t, z in keys),
        gripper=dataclasses.replace(
            base.gripper,
            commands=(
                sim.rig.ScriptedCommand(
                    t_secs=0.3, command="grasp", width_m=0.07, speed_m_per_s=0.05, force_n=12.0
                ),
            ),
        ),
    )
    held = dataclasses.replace(pulled, trajectory=pulled.trajectory[:1])
    out = {}
    for name, scene in (("pull", pulled), ("hold", held)):
        simulator = sim.Simulator(scene)
        trackers = {s: ShearTracker(ShearParams(scale=0.5, warm_start=True)) for s in SIDES}
        above = dict.fromkeys(SIDES, 0)
        pull = PullWatch(0.6, 2)
        decided: dict[str, float] = {}
        stable = False
        for inst, status, feats in stepped(simulator):
            snap = inst.snapshot
            force = -sum(estimate(feats[s], s, cal, "physics").force_n for s in SIDES)
            if status.stable and not stable:
                pull.start(force)
                for side in SIDES:
                    img = inst.images[side]
                    trackers[side].set_reference(
                        img.ir, img.depth_m, PinholeCamera.from_frame(img),
                        tool_basis(img.tool_from_sensor),
                    )  # fmt: skip
            stable = stable or status.stable
            if not stable:
                continue
            if "force" not in decided and pull.update(force):
                decided["force"] = snap.time_secs
            for side in SIDES:
                img = inst.images[side]
                r = trackers[side].update(img.ir, img.depth_m)
                sheared = r.direction_defined and r.magnitude_px >= 1.5
                above[side] = above[side] + 1 if sheared else 0
                if above[side] >= 3 and "shear" not in decided:
                    decided["shear"] = snap.time_secs
        out[name] = decided
    return {"start": start, **out}


def handover_rows(seeds: list[int], cal: Calibration, period_secs: float) -> list[Row]:
    runs = [handover_runs(s, cal) for s in seeds]
    rows: list[Row] = []
    for rule in ("shear", "force"):
        lat = [1000.0 * (r["pull"][rule] - r["start"]) for r in runs if rule in r["pull"]]
        rows.append(
            {
                "sweep": "handover",
                "world": "sim",
                "setting": "decision",
                "method": rule,
                "samples": len(runs),
                "released_fraction": len(lat) / len(runs),
                "release_latency_ms_median": median(lat),
                "release_latency_frames_median": median(lat) / (period_secs * 1000.0),
                "false_release_rate": float(np.mean([rule in r["hold"] for r in runs])),
            }
        )
    return rows
