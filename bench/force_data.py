"""Grasps with known wrenches: the force estimators' calibration and test data.

A *grasp* is a short simulated scene drawn from a seed: an object (mug, PET bottle,
square bottle, wine glass) grasped with a random force, then loaded by its weight, a
filling, or a pull in a random direction of the tool's (y, z) plane, some past the
bubbles' friction (the ``wrench`` and ``slip`` effects, ``sim/friction.py``). Each is
rendered with every sensor effect (ToF noise, IR dots) and turned, frame by frame and
bubble by bubble, into the estimators' features (``perception.force.features``) beside
the world's true wrench and slip: :func:`record`.

The calibration procedure in the simulated world is: record the calibration grasps
(seeds ``0 .. n-1``), fit every method (``perception.force.estimators.calibrate``),
write the file the ``wrench`` node reads::

    python -m bench.force_data --grasps 12 --out models/force/sim.json

On a real rig the same fit runs on grasps whose true wrench comes from known loads or a
wrist force-torque sensor (docs/force.md). ``bench.force`` scores on other seeds.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import sim
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from messages.force import WrenchTruth
from perception.force.estimators import Calibration, Sample, calibrate
from perception.force.features import BubbleFeatures, ContactFeatures, FeatureParams
from perception.grasp import GraspMonitor, GraspStatus
from perception.shear import ShearParams

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ROOT / "models" / "force" / "sim.json"
QUICK_GRASPS, QUICK_SECS = 2, 2.0  # --quick: the load starts at 1 s, so 1 s of it
OBJECTS = {
    # object, held pose (tool xyz), grasp width hint, mass (kg), the reflex's bound on
    # the grip (N: a wine glass takes less; all under the ~20 N where the simulated
    # bubbles bottom out on their plates)
    "mug": ((0.0, 0.0, 0.005), 0.07, 0.35, 18.0),
    "pet_bottle": ((0.0, 0.03, 0.0), 0.06, 0.5, 15.0),
    "square_bottle": ((0.0, 0.015, 0.0), 0.06, 0.5, 15.0),
    "wine_glass": ((0.0, -0.0375, 0.0), 0.05, 0.2, 10.0),
}
LOADS = ("fill", "pull", "still")
EFFECTS = [
    *("membrane", "depth", "tof_noise", "ir", "dot_pattern", "shear", "pressure"),
    *("gripper", "wrench", "slip"),
]


@dataclass(frozen=True)
class GraspSpec:
    """One drawn grasp (see the module docstring)."""

    seed: int
    object: str
    load: str
    grip_n: float
    scene: sim.Scene
    doc: dict[str, object]  # the scene as a document (``sim.scene_from_dict``'s input)


def draw(
    seed: int, *, duration_secs: float = 3.0, load: str | None = None, bounded: bool = False
) -> GraspSpec:
    """The grasp of ``seed``: object, grip, load (``fill``, ``pull``, ``still``). With
    ``bounded``, the grip is at most the object's bound (the reflex's runs: a controller
    does not grasp a wine glass harder than the reflex may squeeze it); the other draws
    are the same either way."""
    rng = np.random.default_rng([seed, 31])
    name = list(OBJECTS)[(seed // len(LOADS)) % len(OBJECTS)]
    xyz, width, mass, bound = OBJECTS[name]
    kind = load or LOADS[seed % len(LOADS)]
    grip = float(rng.uniform(5.0, 12.0))  # the loads scale with the drawn grip
    command = min(grip, bound) if bounded else grip
    angle = float(rng.uniform(0, 2 * np.pi))
    gravity = [0.0, float(np.cos(angle)), float(np.sin(angle))]
    t_load = 1.0
    data: dict[str, object] = {
        "name": f"force_{seed}",
        "seed": 1000 + seed,
        "duration_secs": duration_secs,
        "effects": EFFECTS,
        "object": {"name": name},
        "mount_rpy_deg": [0, -90, -90],
        "trajectory": [{"t_secs": 0.0, "xyz_m": list(xyz)}],
        "gripper": {
            "commands": [
                {
                    "t_secs": 0.1,
                    "command": "grasp",
                    "width_m": width,
                    "speed_m_per_s": 0.08,
                    "force_n": command,
                }
            ]
        },  # fmt: skip
    }
    load_spec: dict[str, object] = {"mass_kg": mass, "gravity_in_tool": gravity}
    if kind == "fill":
        load_spec.update(
            fill_kg_per_s=float(rng.uniform(0.2, 0.8)) * grip / 6.0,
            fill_from_secs=t_load,
            max_mass_kg=5.0,
        )
    elif kind == "pull":
        pull_angle = float(rng.uniform(0, 2 * np.pi))
        peak = float(rng.uniform(0.8, 2.5)) * grip
        direction = [0.0, float(np.cos(pull_angle)), float(np.sin(pull_angle))]
        load_spec["pull"] = [
            {"t_secs": 0.0, "force_n": [0.0, 0.0, 0.0]},
            {"t_secs": t_load, "force_n": [0.0, 0.0, 0.0]},
            {"t_secs": duration_secs, "force_n": [peak * d for d in direction]},
        ]
    data["load"] = load_spec
    scene = sim.scene_from_dict(data, path=f"<force grasp {seed}>")
    return GraspSpec(seed, name, kind, command, scene, data)


@dataclass
class Frame:
    """One frame of a recorded grasp: per side features, truth and timing."""

    t_secs: float
    features: dict[str, ContactFeatures]
    force_n: dict[str, np.ndarray]
    torque_nm: dict[str, np.ndarray]
    slipping: dict[str, float]  # true share of the patch's area slipping
    slide_m: np.ndarray
    feature_secs: float
    # How far the object may slide in the hand and still count as held (``held``): the
    # world's. MuJoCo's shell gives centimetres under a load before the object slips out.
    drop_m: float = 0.010
    # The grasp monitor's stable grasp (``perception.grasp``, fed the pressures and the
    # jaws as the graph's ``grasp_monitor`` is): the slip node's reference starts there.
    stable: bool = False


def free_and_still(snap: sim.WorldSnapshot, scene: sim.Scene) -> bool:
    """The gripper open and still: the free bubble (what the nodes use too)."""
    return snap.width_m >= scene.gripper.max_width_m - 1e-3 and snap.speed_m_per_s < 1e-3


def record(spec: GraspSpec) -> list[Frame]:
    """Render a grasp and extract every frame's features beside its truth."""
    simulator = sim.Simulator(spec.scene)
    extractors = {s: BubbleFeatures() for s in SIDES}
    frames: list[Frame] = []
    while not simulator.world.done:
        inst = simulator.step()
        snap = inst.snapshot
        features: dict[str, ContactFeatures] = {}
        start = time.perf_counter()
        holding = snap.gripper_state == "holding"
        for side in SIDES:
            img = inst.images[side]
            if free_and_still(snap, spec.scene):
                extractors[side].free_frame(img.depth_m, snap.pressure_pa[side])
            if holding and not extractors[side].tared:
                extractors[side].tare(
                    img.ir, img.depth_m, PinholeCamera.from_frame(img), img.tool_from_sensor
                )
            elif snap.width_m >= spec.scene.gripper.max_width_m - 1e-3:
                extractors[side].untare()
            features[side] = extractors[side].update(
                img.ir,
                img.depth_m,
                snap.pressure_pa[side],
                PinholeCamera.from_frame(img),
                img.tool_from_sensor,
                snap.time_secs,
            )
        elapsed = time.perf_counter() - start
        none = sim.friction.BubbleWrench.none()
        frames.append(
            Frame(
                t_secs=snap.time_secs,
                features=features,
                force_n={s: snap.wrench.get(s, none).force_n for s in SIDES},
                torque_nm={s: snap.wrench.get(s, none).torque_nm for s in SIDES},
                slipping={s: snap.wrench.get(s, none).slipping_fraction for s in SIDES},
                slide_m=snap.slide_m.copy(),
                feature_secs=elapsed,
            )
        )
    return frames


SETTINGS = {
    "fb_half": ShearParams(scale=0.5, warm_start=True),
    "fb_quarter": ShearParams(scale=0.25, warm_start=True),
    "dis_half": ShearParams(method="dis", scale=0.5, warm_start=True),
}
DEFAULT_SETTING = "fb_half"  # FeatureParams' default


@dataclass
class Recorded:
    """One grasp's frames, with the features of every setting."""

    frames: list[Frame]
    by_setting: dict[str, list[dict[str, ContactFeatures]]] = field(default_factory=dict)
    frame_secs: float = 0.0


class Bubbles:
    """Both bubbles' feature extraction as the ``wrench`` node does it, for one setting."""

    def __init__(self, flow: ShearParams) -> None:
        self.extractors = {s: BubbleFeatures(FeatureParams(flow=flow)) for s in SIDES}

    def frame(self, inst: sim.Instant, scene: sim.Scene) -> dict[str, ContactFeatures]:
        snap = inst.snapshot
        out = {}
        for side in SIDES:
            img, ext = inst.images[side], self.extractors[side]
            camera = PinholeCamera.from_frame(img)
            if free_and_still(snap, scene):
                ext.free_frame(img.depth_m, snap.pressure_pa[side])
                ext.untare()
            elif snap.gripper_state == "holding" and not ext.tared:
                ext.tare(img.ir, img.depth_m, camera, img.tool_from_sensor)
            out[side] = ext.update(
                img.ir, img.depth_m, snap.pressure_pa[side], camera, img.tool_from_sensor,
                snap.time_secs,
            )  # fmt: skip
        return out


def monitor_step(monitor: GraspMonitor, snap: sim.WorldSnapshot) -> GraspStatus:
    """Feed one snapshot's pressures and jaws to the grasp monitor (as the graph does)."""
    stamp = sim.stamp_of(snap)
    for side in SIDES:
        monitor.update_pressure(side, snap.pressure_pa[side], stamp)
    return monitor.update_gripper(snap.speed_m_per_s, snap.width_m, stamp)


def features_of(
    instants: list[sim.Instant],
    scene: sim.Scene,
    truths: list[WrenchTruth],
    settings: tuple[str, ...] = (),
) -> Recorded:
    """Every setting's (default: all) features of one grasp's frames, beside the truth."""
    bubbles = {name: Bubbles(SETTINGS[name]) for name in settings or SETTINGS}
    rec = Recorded([], {name: [] for name in bubbles})
    # The frames' own features: the default setting's (the nodes', the one the slip and
    # reflex sweeps calibrate with), else the only one recorded.
    main = DEFAULT_SETTING if DEFAULT_SETTING in bubbles else next(iter(bubbles))
    monitor = GraspMonitor()
    for inst, truth in zip(instants, truths, strict=True):
        snap = inst.snapshot
        status = monitor_step(monitor, snap)
        for name, b in bubbles.items():
            rec.by_setting[name].append(b.frame(inst, scene))
        none = sim.friction.BubbleWrench.none()
        rec.frames.append(
            Frame(
                t_secs=snap.time_secs,
                features=rec.by_setting[main][-1],
                force_n={s: truth.bubble_force_n[i] for i, s in enumerate(SIDES)},
                torque_nm={s: truth.bubble_torque_nm[i] for i, s in enumerate(SIDES)},
                slipping={s: snap.wrench.get(s, none).slipping_fraction for s in SIDES},
                slide_m=snap.slide_m.copy(),
                feature_secs=0.0,
                stable=status.stable,
            )
        )
    return rec


DROP_M = Frame.drop_m  # an object that slid this far in the hand is lost: its frames do not count


def held(frame: Frame) -> bool:
    """The object is still in the hand (slid less than its world's ``Frame.drop_m``)."""
    return float(np.hypot(*frame.slide_m)) < frame.drop_m


def shift_errors_m(frames: list[Frame], features: list[dict[str, ContactFeatures]]) -> list[float]:
    """Per bubble and frame while all of its patch sticks: how far the core's dots'
    shift is from the object's slide in the hand since the tare (``world.sim`` renders
    the stuck material moving with the object, so the two are the same motion)."""
    errors: list[float] = []
    for side in SIDES:
        tare: np.ndarray | None = None
        for frame, feats in zip(frames, features, strict=True):
            f = feats[side]
            if not f.tracked:
                tare = None
                continue
            if tare is None:
                tare = frame.slide_m
            if frame.slipping[side] == 0.0:
                errors.append(float(np.linalg.norm(f.core_shift_m - (frame.slide_m - tare))))
    return errors


def samples(frames: list[Frame], grasp: int = 0) -> list[Sample]:
    """Every bubble of every frame while the object is held, as a calibration sample of
    the calibration's ``grasp``-th grasp."""
    return [
        Sample(s, f.features[s], f.force_n[s], f.torque_nm[s], f.slipping[s], grasp)
        for f in frames
        if held(f)
        for s in SIDES
    ]


def calibrate_on(seeds: list[int], *, duration_secs: float = 3.0) -> Calibration:
    """Record the grasps of ``seeds`` and fit every method on them."""
    data: list[Sample] = []
    for k, seed in enumerate(seeds):
        data += samples(record(draw(seed, duration_secs=duration_secs)), k)
    return calibrate(
        data,
        rig="sim",
        source=f"bench.force_data: simulated grasps, seeds {seeds[0]}..{seeds[-1]}",
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.force_data")
    parser.add_argument("--grasps", type=int, default=12, help="calibration grasps (seeds 0..n-1)")
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per grasp")
    parser.add_argument("--out", type=Path, default=CALIBRATION)
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"at most {QUICK_GRASPS} grasps of {QUICK_SECS} s, for smoke tests (as every bench)",
    )
    args = parser.parse_args(argv)
    if args.grasps < 1:
        parser.error("--grasps must be >= 1")
    if args.quick:
        args.grasps = min(args.grasps, QUICK_GRASPS)
        args.duration = min(args.duration, QUICK_SECS)
    cal = calibrate_on(list(range(args.grasps)), duration_secs=args.duration)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cal.save(args.out)
    print(f"wrote {args.out} ({cal.samples} samples; friction {cal.friction:.3f})", file=sys.stderr)


if __name__ == "__main__":
    main()


__all__ = [
    *("CALIBRATION", "DEFAULT_SETTING", "SETTINGS", "Bubbles", "Frame", "GraspSpec"),
    *("Recorded", "calibrate_on", "draw", "features_of", "record", "samples", "shift_errors_m"),
]
