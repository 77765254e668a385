"""Held out on physics no one here tuned: the same grasps on ``world.sim`` and MuJoCo.

Every perception figure the project publishes is measured on its own simulator. This
bench makes a fixed, seeded set of grasps on both worlds and scores the same perception
on each, side by side:

- grasps: the four objects in turn (mug, PET bottle, square bottle, wine glass), each
  held with its axis along tool y at a random offset (up to 4 mm along tool y and z) and
  roll about the grasp axis (up to 8 degrees), seed :data:`SEED`, by its middle (the wine
  glass by its bowl); the gripper grasps at 12 N from 0.05 s; from :data:`HOLD_SECS` the hand slides the object
  :data:`SLIDE_M` along tool z (the pull of a handover); the scene ends at
  :data:`END_SECS` (these grasps, the drawn ones below, their recording and replay:
  ``bench.worlds_grasps``). Each grasp is a scene file written next to its recording.
- the MuJoCo run of a grasp is recorded once to an MCAP bag
  (``<workdir>/grasp_<k>_<digest>.mcap``, the digest of the scene and the mesh:
  ``world/state``, with both membranes' surfaces, and
  ``world/wrench`` per frame, the messages the ``world.mujoco`` node publishes; beside
  it, ``<same>.json``: the recording's CPU cost and the per-frame truth the messages do
  not carry, :func:`recorded_frames`) and the evaluation replays the bag (the cameras render its states); a bag already there is
  reused, so the physics runs once per grasp and mesh. ``world.sim`` is cheap and runs
  live.
- scores, per world: ``contact_iou``: the contact filter's patch (``perception.contact``
  against the first, untouched frame) against the world's true contact, intersection
  over union, at the last held frame; ``lm_*``/``ipopt_*``: the pose estimator
  (``perception.pose``, each solver, cold start, the whole object's field) on that
  frame's grasp cloud against the world's object pose: axis error (degrees, up to the
  axis's sign), off-axis error (mm), and ``silent_wrong``: answers off by more than 2
  degrees or 2 mm along the directions observed whose status was ``ok`` or
  ``recovered`` (:func:`pose_scores`); ``shear_*``: the shear
  tracker (``perception.shear``, default settings: a cold flow), referenced at the last
  held frame, at the end of the slide, against the world's own shear truth (direction
  error in degrees, magnitude error in mm, both bubbles); ``shear_warm_*``: the same
  tracker warm-started (``warm_start``) over every frame of the slide
  (:func:`shear_scores`); ``stable_*``: the grasp monitor
  (``perception.grasp``) on the world's pressures and finger speed: detected, and its
  delay after the jaws hold; ``classifier_right``: the committed classifier
  (``models/tactile_resnet18.pt``, trained on ``world.sim`` only), majority of the held
  frames; ``classifier_drawn_right``: the same classifier on grasps drawn as its
  training grasps were (:func:`drawn_scene`: the auto-labeller's generator,
  ``perception.classify.autolabel``, held-out seed :data:`DRAWN_SEED`; the object placed,
  the jaws closed to the drawn width and force after :data:`SETTLE_SECS`, the training
  frames' effects, no dot pattern), majority of the frames after the grasp monitor calls
  the grasp stable (a grasp never stable is counted wrong); ``world_cpu_s_per_sim_s``: the world's stepping, CPU seconds per simulated
  second (one process; the MuJoCo figure is the recording's).
- cost rows (``mujoco (cost)``): MuJoCo's CPU seconds per simulated second against the
  membrane mesh (12, 8, 5 and 3 mm edges; 12 mm only with ``--quick``) while the jaws
  hold the mug.

    python -m bench.worlds [--quick] [--json] [--variants held_out] [--grasps N] [--model PATH]

``--quick``: one grasp of each kind, a 12 mm membrane mesh, in a temporary folder. The
full run: 8 grasps of each kind, an 8 mm mesh, recordings in ``out/worlds``
(``WORLDS_DIR`` overrides). ``--variants train|held_out``: the classifier's drawn grasps
hold variants of their class from that split (``geometry.variants``; the auto-labeller's
``variants`` option) instead of the reference shapes, and ``--grasps N`` sets how many
(``--model PATH`` scores another classifier checkpoint than the committed one);
only those are run and scored (the bench's own grasps hold the reference shapes the pose
is fitted to, and the cost rows do not depend on the object: neither changes), and the
rows say which split (``variants``).
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import Row, main, median, progress
from bench.shear import angle_error_deg
from bench.worlds_grasps import (
    HOLD_SECS,
    SEED,
    drawn_scene,
    grasp_scene,
    recorded_grasp,
    recorded_scene,
    replay_mujoco,
    run_sim,
)
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from perception.classify.checkpoint import Classifier
from perception.contact import ContactParams, ContactPatcher, contact_mask
from perception.grasp import GraspMonitor
from perception.pose import metrics
from perception.pose.estimator import PoseEstimator
from perception.pose.ipopt import IpoptParams, IpoptSolver
from perception.pose.lm import LMSolver
from perception.shear import ShearParams, ShearTracker, tool_basis
from sim import Instant

COST_FROM_SECS = 0.6
COST_SECS = 0.3
AXIS_OK_DEG = 2.0
OFFAXIS_OK_M = 0.002
MODEL = Path("models/tactile_resnet18.pt")


def _frame(inst: Instant, side: str) -> tuple[np.ndarray, PinholeCamera, np.ndarray]:
    img = inst.images[side]
    return img.depth_m, PinholeCamera.from_frame(img), img.tool_from_sensor


def score(frames: list[Instant], classifier: Classifier) -> dict[str, Any]:
    """Every perception figure on one grasp's frames (see the module docstring)."""
    scene_period = frames[1].snapshot.time_secs - frames[0].snapshot.time_secs
    hold = min(int(round(HOLD_SECS / scene_period)), len(frames) - 1)
    first, held = frames[0], frames[hold]
    truth = held.snapshot.tool_from_object
    assert held.ground_truth is not None
    name = held.ground_truth.object_class
    out: dict[str, Any] = {"object": name}
    # Contact patch against the true contact.
    params = ContactParams()
    ious = []
    for side in SIDES:
        est = contact_mask(held.images[side].depth_m, first.images[side].depth_m, params)
        true = held.masks[side].mask > 0
        union = (est | true).sum()
        ious.append(float((est & true).sum() / union) if union else 1.0)
    out["contact_iou"] = float(np.mean(ious))
    # Pose, cold, both solvers.
    patcher = ContactPatcher(ContactParams(max_points=3000))
    for side in SIDES:
        patcher.update_reference(side, first.images[side].depth_m)
    cloud = patcher.extract({s: _frame(held, s) for s in SIDES})
    out |= pose_scores(name, cloud.points_in_tool.astype(np.float64), cloud.bubble, truth)
    # Shear over the slide, against the world's own truth: the default tracker on the
    # slide's last frame alone, and warm-started over every frame of it.
    out |= shear_scores(frames[hold:], "shear", ShearParams())
    out |= shear_scores(frames[hold:], "shear_warm", ShearParams(warm_start=True))
    # Stable-grasp detection on the world's pressures and finger motion.
    monitor = GraspMonitor()
    stable_at = holding_at = None
    for inst in frames:
        t = inst.snapshot.time_secs
        stamp = inst.stamp_nanos
        g = inst.gripper
        status = monitor.update_gripper(g.speed_m_per_s, g.width_m, stamp)
        for side in SIDES:
            status = monitor.update_pressure(side, inst.pressures[side].pressure_pa, stamp)
        if holding_at is None and g.state == "holding":
            holding_at = t
        if stable_at is None and status.stable:
            stable_at = t
    out["stable_detected"] = int(stable_at is not None and stable_at <= HOLD_SECS)
    out["stable_delay_s"] = (
        stable_at - holding_at if stable_at is not None and holding_at is not None else float("nan")
    )
    # The committed classifier, majority over the held frames.
    votes = []
    for inst in frames[(holding_at and int(round(holding_at / scene_period))) or hold : hold + 1]:
        votes.append(_class_of(classifier, inst))
    said = max(set(votes), key=votes.count) if votes else ""
    out["classifier_said"] = said
    out["classifier_right"] = int(said == name)
    return out


def shear_scores(frames: list[Instant], name: str, params: ShearParams) -> dict[str, Any]:
    """The shear tracker referenced at ``frames[0]`` (the last held frame) against the
    world's shear truth at the last frame: ``<name>_dir_deg`` (direction error, 180 where
    undefined) and ``<name>_err_mm`` (magnitude of the difference), both bubbles'
    mean. A cold tracker sees the last frame alone; a warm-started one every frame of the
    slide, each flow starting from the one before."""
    held, last = frames[0], frames[-1]
    between = frames[1:-1] if params.warm_start else []
    dirs, mags = [], []
    out: dict[str, Any] = {}
    for side in SIDES:
        ref = held.images[side]
        tracker = ShearTracker(params)
        tracker.set_reference(
            ref.ir, ref.depth_m, PinholeCamera.from_frame(ref), tool_basis(ref.tool_from_sensor)
        )
        for inst in [*between, last]:
            result = tracker.update(inst.images[side].ir, inst.images[side].depth_m)
        true_m = last.snapshot.shear_in_tool_m[side] - held.snapshot.shear_in_tool_m[side]
        est_m = np.asarray(result.shear_m, np.float64)
        ok = result.direction_defined and result.metric_defined
        dirs.append(angle_error_deg(est_m, true_m) if ok else 180.0)
        mags.append(float(np.hypot(*(est_m - true_m))) * 1000.0)
        out[f"shear_true_mm_{side}"] = float(np.hypot(*true_m)) * 1000.0
    out[f"{name}_dir_deg"] = float(np.mean(dirs))
    out[f"{name}_err_mm"] = float(np.mean(mags))
    return out


def pose_scores(
    name: str, points_in_tool: np.ndarray, bubble: np.ndarray, truth: np.ndarray
) -> dict[str, Any]:
    """The pose estimator (each solver, cold start, the whole object's field) on one grasp
    cloud against the world's ``tool_from_object``: axis and off-axis error, and
    ``silent_wrong``: ``ok`` or ``recovered`` but off by more than :data:`AXIS_OK_DEG` or
    :data:`OFFAXIS_OK_M` along the directions observed (``metrics.right`` with the
    cloud: a slide or turn that neither the estimate nor the patch at the true pose
    observes, a square bottle's within the faces the jaws hold, is no error; a bottle's
    ends are alike)."""
    from geometry import objects

    model = objects.make(name)
    out: dict[str, Any] = {}
    for solver_name, solver in (
        ("lm", LMSolver(model.field)),
        ("ipopt", IpoptSolver(model.field, IpoptParams(jit="off"))),
    ):
        estimator = PoseEstimator(solver, symmetric_about_z=model.symmetric_about_z)
        result = estimator.estimate(points_in_tool, bubble)
        right = metrics.right(
            model.field,
            result,
            truth,
            angle_deg=AXIS_OK_DEG,
            offset_m=OFFAXIS_OK_M,
            ends_alike=True,
            points_in_tool=points_in_tool,
        )
        out[f"{solver_name}_axis_deg"] = metrics.axis_error_deg(
            result.tool_from_object, truth, flip_symmetric=True
        )
        out[f"{solver_name}_offaxis_mm"] = (
            metrics.offaxis_error_m(result.tool_from_object, truth) * 1000.0
        )
        out[f"{solver_name}_silent_wrong"] = int(result.status in ("ok", "recovered") and not right)
    return out


def _class_of(classifier: Classifier, inst: Instant) -> str:
    """The classifier's answer for one frame pair."""
    p = classifier.classify(
        depth_left_m=inst.images["left"].depth_m,
        depth_right_m=inst.images["right"].depth_m,
        ir_left=inst.images["left"].ir,
        ir_right=inst.images["right"].ir,
    )
    return classifier.meta.classes[int(np.argmax(p))]


def classify_drawn(frames: list[Instant], classifier: Classifier) -> dict[str, Any]:
    """The classifier's majority over the frames after the grasp monitor's stable grasp."""
    monitor = GraspMonitor()
    votes = []
    for inst in frames:
        g = inst.gripper
        status = monitor.update_gripper(g.speed_m_per_s, g.width_m, inst.stamp_nanos)
        for side in SIDES:
            status = monitor.update_pressure(
                side, inst.pressures[side].pressure_pa, inst.stamp_nanos
            )
        if status.stable:
            votes.append(_class_of(classifier, inst))
    assert frames[-1].ground_truth is not None
    name = frames[-1].ground_truth.object_class
    said = max(sorted(set(votes)), key=votes.count) if votes else "not stable"
    return {"drawn_object": name, "drawn_said": said, "classifier_drawn_right": int(said == name)}


def _drawn_summary(world: str, drawn: list[dict[str, Any]]) -> Row:
    """The classifier on the drawn grasps alone."""
    return {
        "world": world,
        "drawn_grasps": len(drawn),
        "classifier_drawn_right_fraction": (
            sum(d["classifier_drawn_right"] for d in drawn) / len(drawn) if drawn else float("nan")
        ),
        "classifier_drawn_wrong": " ".join(
            f"{d['drawn_object']}->{d['drawn_said']}"
            for d in drawn
            if not d["classifier_drawn_right"]
        ),
    }


def _summary(
    world: str, scores: list[dict[str, Any]], cpu: list[float], drawn: list[dict[str, Any]]
) -> Row:
    def med(key: str) -> float:
        return median([s[key] for s in scores if np.isfinite(s[key])] or [float("nan")])

    n = len(scores)
    return {
        "world": world,
        "grasps": n,
        "contact_iou_median": med("contact_iou"),
        "lm_axis_deg_median": med("lm_axis_deg"),
        "lm_offaxis_mm_median": med("lm_offaxis_mm"),
        "ipopt_axis_deg_median": med("ipopt_axis_deg"),
        "ipopt_offaxis_mm_median": med("ipopt_offaxis_mm"),
        "pose_silent_wrong": sum(s["lm_silent_wrong"] + s["ipopt_silent_wrong"] for s in scores),
        "shear_dir_deg_median": med("shear_dir_deg"),
        "shear_err_mm_median": med("shear_err_mm"),
        "shear_warm_dir_deg_median": med("shear_warm_dir_deg"),
        "shear_warm_err_mm_median": med("shear_warm_err_mm"),
        "stable_detected_fraction": sum(s["stable_detected"] for s in scores) / n,
        "stable_delay_s_median": med("stable_delay_s"),
        "classifier_right_fraction": sum(s["classifier_right"] for s in scores) / n,
        "classifier_wrong": " ".join(
            f"{s['object']}->{s['classifier_said']}" for s in scores if not s["classifier_right"]
        ),
        **{k: v for k, v in _drawn_summary(world, drawn).items() if k != "world"},
        "world_cpu_s_per_sim_s": median(cpu),
    }


def cost_rows(spacings_m: tuple[float, ...]) -> list[Row]:
    """MuJoCo's CPU seconds per simulated second against the membrane mesh, in contact.

    The first grasp (the mug) runs to :data:`COST_FROM_SECS` (the jaws hold it), then
    :data:`COST_SECS` more of holding are timed (process CPU time of the stepping, not
    the model's construction and inflation).
    """
    from sim.mujoco.model import ShellSpec
    from sim.mujoco.world import MujocoWorld
    from sim.scene import scene_from_dict

    scene = scene_from_dict(grasp_scene(0, np.random.default_rng(SEED)))
    rows = []
    for spacing in spacings_m:
        world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=spacing))
        while world.frame_index * scene.frame_period_secs < COST_FROM_SECS:
            world.step()
        start, t0 = time.process_time(), world.frame_index * scene.frame_period_secs
        while world.frame_index * scene.frame_period_secs < COST_FROM_SECS + COST_SECS:
            world.step()
        sim_secs = world.frame_index * scene.frame_period_secs - t0
        rows.append(
            {
                "world": "mujoco (cost)",
                "mesh_mm": spacing * 1000.0,
                "vertices_per_bubble": len(world.physics.mesh.rest_m),
                "world_cpu_s_per_sim_s": (time.process_time() - start) / sim_secs,
            }
        )
    return rows


def _vertices(spacing_m: float) -> int:
    from geometry.gripper import BubbleGeometry
    from sim.mujoco.mesh import membrane_mesh

    return len(membrane_mesh(BubbleGeometry(), spacing_m).rest_m)


def run(
    quick: bool, variants: str = "none", drawn_grasps: int | None = None, model: Path = MODEL
) -> list[Row]:
    grasps = 1 if quick else 8
    drawn_grasps = grasps if drawn_grasps is None else drawn_grasps
    if variants != "none":
        grasps = 0  # the bench's own grasps hold the reference shapes: nothing new
    spacing = 0.012 if quick else 0.008
    tmp = tempfile.TemporaryDirectory() if quick else None
    workdir = Path(tmp.name) if tmp else Path(os.environ.get("WORLDS_DIR", "out/worlds"))
    workdir.mkdir(parents=True, exist_ok=True)
    classifier = Classifier.load(model)
    rng = np.random.default_rng(SEED)
    results: dict[str, tuple[list[dict[str, Any]], list[float]]] = {
        "sim": ([], []),
        "mujoco": ([], []),
    }
    drawn_results: dict[str, list[dict[str, Any]]] = {"sim": [], "mujoco": []}
    try:
        for k in progress(range(grasps), "bench.worlds", label=lambda k: f"grasp {k}"):
            scene_path, bag, mujoco_cpu = recorded_grasp(k, rng, spacing, workdir)
            frames, cpu = run_sim(scene_path)
            results["sim"][0].append(score(frames, classifier))
            results["sim"][1].append(cpu)
            results["mujoco"][0].append(score(replay_mujoco(scene_path, bag), classifier))
            results["mujoco"][1].append(mujoco_cpu)
        for k in progress(range(drawn_grasps), "bench.worlds", label=lambda k: f"drawn {k}"):
            drawn_path, drawn_bag, _ = recorded_scene(
                f"drawn_{k}", drawn_scene(k, variants), spacing, workdir
            )
            drawn_results["sim"].append(classify_drawn(run_sim(drawn_path)[0], classifier))
            drawn_results["mujoco"].append(
                classify_drawn(replay_mujoco(drawn_path, drawn_bag), classifier)
            )
    finally:
        if tmp is not None:
            tmp.cleanup()
    rows = [
        (_summary(w, s, c, drawn_results[w]) if grasps else _drawn_summary(w, drawn_results[w]))
        | {
            "variants": variants,
            "mesh_mm": spacing * 1000 if w == "mujoco" else None,
            "vertices_per_bubble": _vertices(spacing) if w == "mujoco" else None,
        }
        for w, (s, c) in results.items()
    ]
    if variants != "none":
        return rows
    return rows + cost_rows((0.012,) if quick else (0.012, 0.008, 0.005, 0.003))


def cli(argv: list[str] | None = None) -> list[Row]:
    """``main`` with this bench's own options (``--variants``, ``--grasps``, ``--model``)."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--variants", choices=("none", "train", "held_out"), default="none")
    parser.add_argument("--grasps", type=int, default=None, help="drawn grasps (default: 8, 1)")
    parser.add_argument("--model", type=Path, default=MODEL, help="the classifier scored")
    args, rest = parser.parse_known_args(argv)
    if args.grasps is not None and args.grasps < 1:
        parser.error(f"--grasps must be >= 1, got {args.grasps}")
    return main(
        "worlds",
        functools.partial(run, variants=args.variants, drawn_grasps=args.grasps, model=args.model),
        argv=rest,
    )


if __name__ == "__main__":
    cli()
