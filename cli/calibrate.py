"""``launch.py calibrate``: connect the rig's devices, run the procedure, write the file.

The procedure is ``perception.calibration.procedure``; with ``--emulate`` the devices are
the emulated rig's and its lab (``sim.emulated_lab``) vents the bubbles and places the
cylinder; otherwise a person does, told what to do at each step.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack
from typing import Any

import numpy as np


class PromptLab:
    """The lab is a person: each step says what to do and waits for Enter."""

    def __init__(self, radius_mm: float) -> None:
        self.radius_mm = radius_mm
        self.grasp = 0

    def _ask(self, text: str) -> None:
        input(f"    -> {text}, then press Enter ")

    def vent(self, vented: bool) -> None:
        self._ask("open both bubbles to the air" if vented else "close and inflate both bubbles")

    def place(self, tool_from_object: np.ndarray | None) -> None:
        if tool_from_object is None:
            self._ask("take everything away from the bubbles")
            return
        self.grasp += 1
        self._ask(
            f"hold the {self.radius_mm:g} mm cylinder between the bubbles (grasp {self.grasp}:"
            " change its angle and place each time; the gripper closes on it)"
        )


def main(args: argparse.Namespace) -> int:
    from devices import mcp2221
    from devices.abp import COUNTS_MAX, COUNTS_MIN, PSI_PA, AbpSensor
    from devices.royale import RoyaleCamera
    from devices.wsg50_client import WSG50Client
    from messages.errors import DeviceError
    from perception.calibration.procedure import Plan, calibrate

    if args.out.exists() and not args.overwrite:
        print(f"calibrate: {args.out} exists (--overwrite to replace it)", file=sys.stderr)
        return 2
    if not 3 <= args.grasps <= 6:
        args.parser.error("--grasps must be 3 to 6")
    with ExitStack() as stack:
        lab: Any
        if args.emulate:
            from sim.emulated_lab import CALIBRATION_POSES, EmulatedLab

            lab = EmulatedLab(args.rig)
            stack.callback(lab.close)
            host, port = lab.wsg50_address
            ids = {s: lab.rig.cameras[s].camera_id for s in ("left", "right")}
            serials = {s: lab.rig.pressure[s].serial for s in ("left", "right")}
            poses = list(CALIBRATION_POSES[: args.grasps])
        else:
            lab = PromptLab(args.radius_mm)
            host, port = args.address, args.port
            ids = {"left": args.left_camera, "right": args.right_camera}
            serials = {"left": args.left_bridge, "right": args.right_bridge}
            poses = [(None, f) for f in (6.0, 12.0, 9.0, 5.0, 15.0, 8.0)[: args.grasps]]
        try:
            backend = mcp2221.default_backend()
            sensors = {}
            for side, serial in serials.items():
                bridge = mcp2221.MCP2221(serial, backend=backend)
                bridge.connect()
                stack.callback(bridge.disconnect)
                sensors[side] = AbpSensor(bridge)
            cameras = {}
            for side, camera_id in ids.items():
                camera = RoyaleCamera(camera_id, use_case=args.use_case)
                camera.connect()
                stack.callback(camera.disconnect)
                cameras[side] = camera
            gripper = WSG50Client(host, port)
            gripper.connect()
            stack.callback(gripper.disconnect)
            calibration, _ = calibrate(
                rig=args.name or args.out.stem,
                sensors=sensors,
                cameras=cameras,
                gripper=gripper,
                lab=lab,
                plan=Plan(radius_m=args.radius_mm / 1000.0, poses=poses),
                resolution_pa=PSI_PA / (COUNTS_MAX - COUNTS_MIN),
            )
        except (DeviceError, TimeoutError, ValueError) as err:
            print(f"calibrate: {err}", file=sys.stderr)
            return 1
    calibration.save(args.out)
    print(
        f"{args.out}: written; use it with --set NODE.calibration={args.out} on each camera and pressure node"
    )
    return 0
