"""A rig's calibration: how far off an as-built rig is, what calibration recovers, what it buys.

One run, in this process:

1. an as-built rig (``sim.emulated_rig``): each camera 2 degrees and 2 mm off its CAD
   mount (in different directions), intrinsics off nominal, each pressure sensor with an
   offset, a gain error and noise;
2. the calibration (``perception.calibration.procedure``) through the rig's own drivers
   (``devices.rig``: royale, MCP2221A + ABP, WSG 50) against the emulated devices, its
   lab placing the cylinder (``sim.emulated_lab``), in real time;
3. the mug held at several poses: both as-built cameras render it, the royale driver
   converts the SDK's points (``devices.royale.convert``), the frames are placed in the
   tool frame with the CAD mounts and with the calibrated ones, side by side, and the
   contact patch (``perception.contact``) and the pose (``perception.pose``, LM, cold
   start) are computed from each; the error is against the world's truth.

Rows: ``mount`` per side (error before and after, the calibration's own 1-sigma),
``pressure`` per side (true offset, found, error, the sensor's resolution: one count),
``pose`` per mounting (axis degrees and off-axis millimetres, median and max over the
held poses; the axis as a line: from the body's contact alone a cold start cannot tell
the mug's top from its bottom).

    python -m bench.rig [--quick] [--json]
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench.common import Row, main, median
from devices.abp import COUNTS_MAX, COUNTS_MIN, PSI_PA
from devices.rig import connect
from devices.royale import convert
from geometry import objects
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES, GripperGeometry
from geometry.mount import CameraMounts
from geometry.se3 import invert, log_so3, make_pose, rotation_about
from perception.calibration.procedure import Plan, calibrate
from perception.contact import ContactParams, ContactPatcher
from perception.pose import EstimatorParams, LMSolver, PoseEstimator
from perception.pose.metrics import axis_error_deg, offaxis_error_m
from sim import World, render_grasp
from sim.emulated_lab import AWAY, CALIBRATION_POSES, EmulatedLab
from sim.emulated_rig import as_built_renderer, load_rig, sdk_points
from sim.scene import load_scene

COLUMNS = [
    "case", "side", "before_deg", "before_mm", "after_deg", "after_mm", "sigma_deg", "sigma_mm",
    "true_pa", "found_pa", "error_pa", "resolution_pa",
    "mounts", "axis_deg_median", "axis_deg_max", "offaxis_mm_median", "offaxis_mm_max", "poses",
]  # fmt: skip
RESOLUTION_PA = PSI_PA / (COUNTS_MAX - COUNTS_MIN)
HANDOVER = Path("scenes/rig_handover.yaml")


def as_built_rig(path: Path, deg: float = 2.0, mm: float = 2.0) -> Path:
    """Write an as-built rig file with each camera ``deg`` and ``mm`` off its CAD mount."""
    # Roll, pitch and yaw along a unit vector times ``deg``: within a thousandth of a
    # degree of that rotation vector (the rows report the angle of the rotation made).
    axes = {"left": np.array([1.0, -1.0, 1.0]), "right": np.array([-1.0, 1.0, 0.5])}
    offsets = {"left": np.array([1.0, 1.0, -1.0]), "right": np.array([-0.5, 1.0, 1.0])}
    doc: dict[str, Any] = {"rig": f"asbuilt-{deg:g}deg-{mm:g}mm", "cameras": {}, "pressure": {}}
    lens = {"left": (189.2, 205.9, 113.1, 84.2), "right": (184.7, 209.3, 110.2, 86.9)}
    for side in SIDES:
        rpy = axes[side] / np.linalg.norm(axes[side]) * deg
        xyz = offsets[side] / np.linalg.norm(offsets[side]) * mm
        fx, fy, cx, cy = lens[side]
        doc["cameras"][side] = {
            "camera_id": f"EMU-CAM-{side[0].upper()}-BENCH",
            "rpy_deg": [float(v) for v in rpy],
            "xyz_mm": [float(v) for v in xyz],
            "intrinsics": {"fx": fx, "fy": fy, "cx": cx, "cy": cy},
        }
    doc["pressure"] = {
        "left": {"serial": "EMU-BUBBLE-L-BENCH", "offset_pa": 41.0, "gain": 1.03, "noise_pa": 0.8},
        "right": {
            "serial": "EMU-BUBBLE-R-BENCH",
            "offset_pa": -27.5,
            "gain": 0.98,
            "noise_pa": 0.8,
        },
    }
    path.write_text(yaml.safe_dump(doc))
    return path


def mount_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(degrees, millimetres) between two mounts."""
    d = invert(a) @ b
    return float(np.degrees(np.linalg.norm(log_so3(d[:3, :3])))), float(
        np.linalg.norm(d[:3, 3]) * 1e3
    )


def grasp_width(world: World, pose: np.ndarray, force_n: float) -> float:
    """The opening at which the jaws squeeze the object with ``force_n`` (bisection)."""
    lo, hi = 0.02, 0.11
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if world.grip_force_n(mid, pose) > force_n else (lo, mid)
    return 0.5 * (lo + hi)


def held_poses(count: int) -> list[np.ndarray]:
    """The handover's mug pose, and that pose tilted and moved a little."""
    base = load_scene(HANDOVER).tool_from_object(0.0)
    moves = [
        (0.0, 0.0, (0, 0, 0)), (8.0, 0.0, (0, 0, 4)), (-8.0, 0.0, (0, 2, -3)),
        (0.0, 10.0, (0, -3, 2)), (5.0, -6.0, (0, 0, 8)), (-4.0, 6.0, (0, 3, 0)),
    ]  # fmt: skip
    poses = []
    for about_x, about_z, xyz_mm in moves[:count]:
        rot = rotation_about(np.array([1.0, 0, 0]), math.radians(about_x)) @ rotation_about(
            np.array([0, 0, 1.0]), math.radians(about_z)
        )
        poses.append(make_pose(rot, np.array(xyz_mm) / 1000.0) @ base)
    return poses


def pose_rows(rig_file: Path, mounts: dict[str, CameraMounts], count: int) -> list[Row]:
    """Pose error of the held mug with each mounting (module docstring, step 3)."""
    rig = load_rig(rig_file)
    scene = load_scene(HANDOVER)
    world = World(scene)
    renderers = {s: as_built_renderer(scene, s, rig.cameras[s]) for s in SIDES}

    def frames(
        pose: np.ndarray, width: float, index: int
    ) -> dict[str, tuple[np.ndarray, PinholeCamera]]:
        snap = render_grasp("mug", pose, width, effects=scene.effects, scene=scene).snapshot
        out = {}
        for side, renderer in renderers.items():
            frame = renderer.render(dataclasses.replace(snap, frame_index=index))
            depth, _ = convert(sdk_points(frame.arrays, renderer.camera))
            out[side] = (depth, renderer.camera)
        return out

    free = [frames(AWAY, 0.11, k) for k in range(5)]
    held = []
    for k, pose in enumerate(held_poses(count)):
        width = grasp_width(world, pose, 6.0)
        held.append((pose, width, frames(pose, width, 100 + k)))
    fld = objects.make("mug").field
    rows = []
    for name, mounting in mounts.items():
        patcher = ContactPatcher(ContactParams())
        for f in free:
            for side in SIDES:
                patcher.update_reference(side, f[side][0])
        estimator = PoseEstimator(
            LMSolver(fld), EstimatorParams(max_points=3000), symmetric_about_z=fld.revolves_about_z
        )
        axis, off = [], []
        for truth, width, f in held:
            cloud = patcher.extract(
                {s: (f[s][0], f[s][1], mounting.tool_from_sensor(s, width)) for s in SIDES}
            )
            estimator.reset()
            fit = estimator.estimate(cloud.points_in_tool, cloud.bubble)
            estimate = invert(fit.object_from_tool)
            axis.append(axis_error_deg(estimate, truth, flip_symmetric=True))
            off.append(offaxis_error_m(estimate, truth) * 1000.0)
        rows.append(
            {
                "case": "pose",
                "mounts": name,
                "axis_deg_median": median(axis),
                "axis_deg_max": max(axis),
                "offaxis_mm_median": median(off),
                "offaxis_mm_max": max(off),
                "poses": len(held),
            }
        )
    return rows


def run(quick: bool) -> list[Row]:
    with tempfile.TemporaryDirectory() as tmp:
        rig_file = as_built_rig(Path(tmp) / "asbuilt.yaml")
        rig = load_rig(rig_file)
        lab = EmulatedLab(str(rig_file))
        try:
            devices = connect(
                bridges={s: rig.pressure[s].serial for s in SIDES},
                cameras={s: rig.cameras[s].camera_id for s in SIDES},
                address=lab.wsg50_address,
                use_case="MODE_9_5FPS_2000",
            )
            try:
                plan = Plan(
                    radius_m=0.03,
                    poses=CALIBRATION_POSES[: 4 if quick else 6],
                    zero_readings=100 if quick else 300,
                    free_frames=10 if quick else 20,
                    grasp_frames=3 if quick else 4,
                )
                calibration, _ = calibrate(
                    rig=rig.rig,
                    sensors=devices.sensors,
                    cameras=devices.cameras,
                    gripper=devices.gripper,
                    lab=lab,
                    plan=plan,
                    resolution_pa=RESOLUTION_PA,
                    say=lambda _line: None,
                )
            finally:
                devices.close()
        finally:
            lab.close()
        cad = GripperGeometry().finger_from_sensor()
        rows: list[Row] = []
        for side in SIDES:
            true = cad @ rig.cameras[side].mount_error
            found = calibration.cameras[side]
            before = mount_error(true, cad)
            after = mount_error(true, found.finger_from_sensor)
            rows.append(
                {
                    "case": "mount",
                    "side": side,
                    "before_deg": before[0],
                    "before_mm": before[1],
                    "after_deg": after[0],
                    "after_mm": after[1],
                    "sigma_deg": found.rotation_sigma_deg,
                    "sigma_mm": found.translation_sigma_mm,
                }
            )
        for side in SIDES:
            true_pa = rig.pressure[side].offset_pa
            found_pa = calibration.pressure[side].offset_pa
            rows.append(
                {
                    "case": "pressure",
                    "side": side,
                    "true_pa": true_pa,
                    "found_pa": found_pa,
                    "error_pa": abs(found_pa - true_pa),
                    "resolution_pa": RESOLUTION_PA,
                }
            )
        mountings = {"cad": CameraMounts(), "calibrated": calibration.mounts()}
        rows += pose_rows(rig_file, mountings, 3 if quick else 6)
        return rows


if __name__ == "__main__":
    main("rig", run, columns=COLUMNS)
