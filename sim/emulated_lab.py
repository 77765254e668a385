"""The lab around an emulated rig, for a calibration run in one process.

:class:`EmulatedLab` runs the world of ``scenes/rig_calibration.yaml`` (the calibration
cylinder) in real time on a thread, serves its jaws as a WSG 50 on a free loopback port
and publishes its states on the emulated rig's feed (``sim.emulated_rig``), so the
calibration's drivers (``devices.royale``, ``devices.mcp2221`` with ``devices.abp``,
``devices.wsg50_client``) read emulated devices exactly as the hardware graph's nodes do.
It also has the lab's hands: :meth:`vent` opens the bubbles to the air (the gauge
pressure falls to 0) or closes them again, and :meth:`place` puts the cylinder at a pose
between the fingers (or takes it away). :data:`CALIBRATION_POSES` are the poses the
calibration asks a lab to hold the cylinder at.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import zmq

from geometry.se3 import make_pose, rotation_about
from messages.codec import encode
from sim.emulated_rig import AsBuiltRig
from sim.rig_launch import activate
from sim.scene import load_scene
from sim.wire import to_message
from sim.world import World
from sim.wsg50_server import WSG50Server

CALIBRATION_SCENE = Path(__file__).resolve().parent.parent / "scenes" / "rig_calibration.yaml"
AWAY = make_pose(trans=np.array([0.0, 0.0, 1.0]))  # no object between the fingers


def _axis_pose(axis: tuple[float, float, float], xyz_mm: tuple[float, float, float]) -> np.ndarray:
    """A cylinder pose: its axis (object z) along ``axis`` (tool frame), centred at ``xyz_mm``."""
    z = np.array([0.0, 0.0, 1.0])
    target = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.cross(z, target)
    angle = float(np.arctan2(np.linalg.norm(cross), z @ target))
    rot = rotation_about(cross / np.linalg.norm(cross), angle) if angle > 1e-9 else np.eye(3)
    return make_pose(rot, np.asarray(xyz_mm, float) / 1000.0)


# (cylinder pose, grasp force): its axis across the fingers, along them and tilted, off
# centre, squeezed at several forces (so at several openings).
CALIBRATION_POSES: tuple[tuple[np.ndarray, float], ...] = (
    (_axis_pose((0, 1, 0), (0, 0, 0)), 6.0),
    (_axis_pose((0, 0, 1), (0, 0, 0)), 12.0),
    (_axis_pose((0, 1, 0.35), (0, 0, 12)), 9.0),
    (_axis_pose((0, 0.4, 1), (0, 8, -5)), 5.0),
    (_axis_pose((0, 1, -0.3), (0, -5, -10)), 15.0),
    (_axis_pose((0, -0.3, 1), (0, -10, 6)), 8.0),
)


class EmulatedLab:
    """The world, the WSG 50 and the feed of an emulated rig, stepped on a thread."""

    def __init__(self, rig_file: str | None = None) -> None:
        self.rig: AsBuiltRig
        self.rig, feed, self.folder = activate(rig_file, scene=str(CALIBRATION_SCENE))
        self.scene = load_scene(CALIBRATION_SCENE)
        self.world = World(self.scene)
        self.world.place(AWAY)
        self.server = WSG50Server(self.world.dynamics, port=0).start()
        self.socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.PUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.bind(feed)
        self.vented = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="emulated-lab", daemon=True)
        self._thread.start()

    @property
    def wsg50_address(self) -> tuple[str, int]:
        host, port = self.server.address.rsplit(":", 1)
        return host, int(port)

    def vent(self, vented: bool) -> None:
        """Open the bubbles to the air (gauge 0 Pa), or close and inflate them again."""
        self.vented = vented

    def place(self, tool_from_object: np.ndarray | None) -> None:
        """Hold the cylinder at a pose in the tool frame (None: take it away)."""
        self.world.place(AWAY if tool_from_object is None else tool_from_object)

    def _run(self) -> None:
        period = self.scene.frame_period_secs
        start = time.time_ns()
        due = time.monotonic()
        while not self._stop.is_set():
            due += period
            snap = self.server.stepped(self.world.step)
            msg = to_message(snap, self.scene, start + int(round(snap.time_secs * 1e9)))
            if self.vented:
                msg.pressure_pa = [0.0 for _ in msg.pressure_pa]
            self.socket.send_multipart(encode("rig/state", msg), copy=False)
            self._stop.wait(max(0.0, due - time.monotonic()))
            if self.world.done:
                return  # the scene lasts an hour: longer than any calibration

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.server.close()
        self.socket.close(0)
