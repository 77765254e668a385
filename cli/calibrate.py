"""``launch.py calibrate``: connect the rig's devices, run the procedure, write the file.

The procedure is ``perception.calibration.procedure``; the devices are opened by
``devices.rig``. With ``--emulate`` they are the emulated rig's, and its lab
(``sim.emulated_lab``) vents the bubbles and places the cylinder; otherwise a person
does, told what to do at each step.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

SIDES = ("left", "right")
FORCES_N = (6.0, 12.0, 9.0, 5.0, 15.0, 8.0)  # a grasp's force: several openings


class PromptLab:
    """The lab is a person: each step says what to do and waits for Enter."""

    def __init__(self, radius_mm: float) -> None:
        self.radius_mm = radius_mm
        self.grasp = 0

    def vent(self, vented: bool) -> None:
        what = "open both bubbles to the air" if vented else "close and inflate both bubbles"
        input(f"    -> {what}, then press Enter ")

    def place(self, tool_from_object: np.ndarray | None) -> None:
        if tool_from_object is None:
            input("    -> take everything away from the bubbles, then press Enter ")
            return
        self.grasp += 1
        input(
            f"    -> hold the {self.radius_mm:g} mm cylinder between the bubbles (grasp"
            f" {self.grasp}: another angle and place each time), then press Enter "
        )


def main(args: argparse.Namespace) -> int:
    from devices.abp import COUNTS_MAX, COUNTS_MIN, PSI_PA
    from devices.rig import connect
    from messages.errors import DeviceError
    from perception.calibration.procedure import Plan, calibrate

    if args.out.exists() and not args.overwrite:
        print(f"calibrate: {args.out} exists (--overwrite to replace it)", file=sys.stderr)
        return 2
    if not 3 <= args.grasps <= 6:
        args.parser.error("--grasps must be 3 to 6")
    lab: Any
    poses: list[tuple[np.ndarray | None, float]]
    if args.emulate:
        from sim.emulated_lab import CALIBRATION_POSES, EmulatedLab

        lab = EmulatedLab(args.rig)
        address = lab.wsg50_address
        ids = {s: lab.rig.cameras[s].camera_id for s in SIDES}
        serials = {s: lab.rig.pressure[s].serial for s in SIDES}
        poses = list(CALIBRATION_POSES[: args.grasps])
    else:
        lab = PromptLab(args.radius_mm)
        address = (args.address, args.port)
        ids = {"left": args.left_camera, "right": args.right_camera}
        serials = {"left": args.left_bridge, "right": args.right_bridge}
        poses = [(None, f) for f in FORCES_N[: args.grasps]]  # the person picks each pose
    try:
        rig = connect(bridges=serials, cameras=ids, address=address, use_case=args.use_case)
        try:
            calibration, _ = calibrate(
                rig=args.name or args.out.stem,
                sensors=rig.sensors,
                cameras=rig.cameras,
                gripper=rig.gripper,
                lab=lab,
                plan=Plan(radius_m=args.radius_mm / 1000.0, poses=poses),
                resolution_pa=PSI_PA / (COUNTS_MAX - COUNTS_MIN),
            )
        finally:
            rig.close()
    except (DeviceError, TimeoutError, ValueError) as err:
        print(f"calibrate: {err}", file=sys.stderr)
        return 1
    finally:
        if args.emulate:
            lab.close()
    calibration.save(args.out)
    print(
        f"{args.out}: written; the hardware graph reads it with"
        f" --set NODE.calibration={args.out} on each camera and pressure node"
    )
    return 0
