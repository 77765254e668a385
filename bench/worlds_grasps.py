"""The grasps ``bench.worlds`` scores, made on each world: the seeded scene documents
(:func:`grasp_scene`, :func:`drawn_scene`), MuJoCo's runs recorded once to MCAP bags and
reused by the digest of the scene and the mesh (:func:`recorded_scene`), replayed through
the cameras' rendering (:func:`replay_mujoco`), and ``world.sim`` run live
(:func:`run_sim`). ``bench.force`` and ``bench.force_mujoco`` record and replay the same
grasps (``bench.worlds``' docstring says what each grasp is)."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim import Instant, Simulator, load_scene
from sim.world import World

SEED = 29
OBJECTS = ("mug", "pet_bottle", "square_bottle", "wine_glass")
HOLD_SECS = 1.2
SLIDE_M = 0.004
END_SECS = 1.7
# Where along its axis each object is grasped (object z, m): the middle, but the wine
# glass by its bowl (its middle is the thin stem).
GRASP_AT_M = {"wine_glass": 0.0375}
EFFECTS = ["membrane", "depth", "tof_noise", "ir", "dot_pattern", "shear", "pressure"]
EFFECTS += ["gripper", "ground_truth"]
# The classifier's own grasps: a seed no training or held-out set of models/ used, the
# auto-labelling world's effects and pacing (nodes/autolabel.py).
DRAWN_SEED = 2900
DRAWN_EFFECTS = ["membrane", "depth", "ir", "tof_noise", "pressure", "gripper", "ground_truth"]
SETTLE_SECS = 0.2
OPEN_WIDTH_M = 0.11
CLOSE_SPEED_M_PER_S = 0.1
DRAWN_HOLD_SECS = 0.5


def grasp_scene(k: int, rng: np.random.Generator) -> dict[str, Any]:
    """The ``k``-th grasp as a scene document."""
    from sim.scene import rotation_from_rpy_deg

    dy, dz = rng.uniform(-0.004, 0.004, 2)
    roll = float(rng.uniform(-8.0, 8.0))
    name = OBJECTS[k % len(OBJECTS)]
    # The held frame's position that puts the grasped point of the axis at the target.
    rot = rotation_from_rpy_deg((roll, 0.0, 0.0)) @ rotation_from_rpy_deg((0.0, -90.0, -90.0))
    grasped = rot @ np.array([0.0, 0.0, GRASP_AT_M.get(name, 0.0)])
    start = [float(v) for v in np.array([0.0, dy, 0.005 + dz]) - grasped]
    end = [start[0], start[1], start[2] + SLIDE_M]
    return {
        "name": f"worlds_grasp_{k}",
        "seed": SEED * 100 + k,
        "duration_secs": END_SECS,
        "effects": EFFECTS,
        "object": {"name": name},
        "mount_rpy_deg": [0, -90, -90],
        "gripper": {
            "commands": [
                {
                    "t_secs": 0.05,
                    "command": "grasp",
                    "width_m": 0.07,
                    "speed_m_per_s": 0.1,
                    "force_n": 12.0,
                }
            ]
        },
        "trajectory": [
            {"t_secs": 0.0, "xyz_m": start, "rpy_deg": [roll, 0, 0]},
            {"t_secs": HOLD_SECS, "xyz_m": start, "rpy_deg": [roll, 0, 0]},
            {"t_secs": END_SECS, "xyz_m": end, "rpy_deg": [roll, 0, 0]},
        ],
    }


def drawn_scene(k: int, variants: str = "none") -> dict[str, Any]:
    """The ``k``-th grasp of the auto-labeller's generator (seed :data:`DRAWN_SEED`, its
    ``variants`` option) as a scene document: placed, settled, closed to its width and
    force, held at least :data:`DRAWN_HOLD_SECS`."""
    from perception.classify.autolabel import GraspGenerator, GraspGeneratorParams
    from sim.scene import rpy_deg_from_rotation

    sample = GraspGenerator(GraspGeneratorParams(seed=DRAWN_SEED, variants=variants)).sample(k)
    obj: dict[str, Any] = {"name": sample.object_name}
    if sample.variant is not None:
        obj["variant"] = sample.variant
    pose = sample.tool_from_object
    # A grasp command closes until the force is reached, past the drawn width if the
    # membrane gives: time for the whole stroke.
    closing = OPEN_WIDTH_M / CLOSE_SPEED_M_PER_S
    return {
        "name": f"worlds_drawn_{k}",
        "seed": DRAWN_SEED * 100 + k,
        "duration_secs": round(SETTLE_SECS + closing + DRAWN_HOLD_SECS, 3),
        "effects": DRAWN_EFFECTS,
        "object": obj,
        "mount_rpy_deg": [0, 0, 0],
        "gripper": {
            "initial_width_m": OPEN_WIDTH_M,
            "commands": [
                {
                    "t_secs": SETTLE_SECS,
                    "command": "grasp",
                    "width_m": sample.grasp_width_m,
                    "speed_m_per_s": CLOSE_SPEED_M_PER_S,
                    "force_n": sample.force_n,
                }
            ],
        },
        "trajectory": [
            {
                "t_secs": 0.0,
                "xyz_m": [float(v) for v in pose[:3, 3]],
                "rpy_deg": list(rpy_deg_from_rotation(pose[:3, :3])),
            }
        ],
    }


def record_mujoco(scene_path: Path, bag: Path, mesh_spacing_m: float) -> float:
    """Run a scene in MuJoCo and record what ``world.mujoco`` publishes; CPU s per sim s."""
    from runtime.bag import BagWriter
    from sim import stamp_of
    from sim.mujoco.model import ShellSpec
    from sim.mujoco.world import MujocoWorld
    from sim.wire import to_message

    scene = load_scene(scene_path)
    start = time.process_time()
    world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=mesh_spacing_m))
    # What the messages do not carry: the engine's share of each bubble's contacts at
    # their friction cone's limit, and the object's slide in the hand (``slip``).
    frames: list[dict[str, list[float]]] = []
    part = bag.with_suffix(".part")
    with BagWriter(part) as writer:
        writer.add_run_info(
            graph_text="", command_line=f"python -m bench.worlds (mesh {mesh_spacing_m} m)"
        )
        while not world.done:
            snap = world.step()
            stamp = stamp_of(snap)
            writer.write_message("world/state", to_message(snap, scene, stamp), stamp)
            writer.write_message("world/wrench", world.wrench_truth(stamp), stamp)
            assert world.truth is not None
            frames.append(
                {
                    "slipping": list(world.truth.contacts.slipping_fraction),
                    "slide_m": [float(v) for v in snap.slide_m],
                    "load_n": [float(v) for v in snap.load_n],
                }
            )
    cpu = (time.process_time() - start) / scene.duration_secs
    part.replace(bag)
    bag.with_suffix(".json").write_text(json.dumps({"cpu_s_per_sim_s": cpu, "frames": frames}))
    return cpu


def recorded_grasp(
    k: int, rng: np.random.Generator, spacing_m: float, workdir: Path
) -> tuple[Path, Path, float]:
    """The ``k``-th grasp's scene file and its MuJoCo bag in ``workdir`` (recorded now if
    missing), and the recording's CPU seconds per simulated second.

    Both are named by the digest of the scene and the mesh: a changed grasp or mesh is
    recorded again, an unchanged one reused (by this bench and ``bench.force``).
    """
    return recorded_scene(f"grasp_{k}", grasp_scene(k, rng), spacing_m, workdir)


def recorded_scene(
    stem: str, doc: dict[str, Any], spacing_m: float, workdir: Path, *, frames: bool = False
) -> tuple[Path, Path, float]:
    """A scene document's file and its MuJoCo bag (see :func:`recorded_grasp`); with
    ``frames``, one whose per-frame truth beside it (:func:`recorded_frames`) is there
    (recordings made before it was kept are made again)."""
    text = yaml.safe_dump(doc, sort_keys=False)
    key = hashlib.sha256(f"{text}{spacing_m}".encode()).hexdigest()[:10]
    scene_path = workdir / f"{stem}_{key}.yaml"
    scene_path.write_text(text)
    bag = scene_path.with_suffix(".mcap")
    info = bag.with_suffix(".json")
    kept = json.loads(info.read_text()) if bag.exists() and info.exists() else {}
    if "cpu_s_per_sim_s" in kept and (not frames or "frames" in kept):
        cpu = kept["cpu_s_per_sim_s"]
    else:
        cpu = record_mujoco(scene_path, bag, spacing_m)
    return scene_path, bag, float(cpu)


def recorded_frames(bag: Path) -> list[dict[str, list[float]]]:
    """The per-frame truth the messages do not carry, kept beside a bag: ``slipping``
    (each bubble's share of contacts at their friction cone's limit), ``slide_m`` (the
    object's slide in the hand, tool (y, z)) and ``load_n`` (the load on it, tool frame;
    zero until the hand lets go), the last two with the ``slip`` effect."""
    return list(json.loads(bag.with_suffix(".json").read_text())["frames"])


def replay_mujoco(scene_path: Path, bag: Path) -> list[Instant]:
    """Render every recorded state of a MuJoCo bag, as the camera nodes would."""
    from runtime.bag import BagReader
    from sim.wire import from_message

    simulator = Simulator(load_scene(scene_path))
    with BagReader(bag) as reader:
        states = [m.decode() for m in reader.messages(["world/state"])]
    return [simulator.render_snapshot(from_message(s)) for s in states]  # type: ignore[arg-type]


def run_sim(scene_path: Path) -> tuple[list[Instant], float]:
    """Step and render a scene on ``world.sim``; CPU s per simulated second of the world."""
    scene = load_scene(scene_path)
    simulator = Simulator(scene)
    world: World = simulator.world
    cpu = 0.0
    out = []
    while not world.done:
        start = time.process_time()
        snap = world.step()
        cpu += time.process_time() - start
        out.append(simulator.render_snapshot(snap))
    return out, cpu / scene.duration_secs
