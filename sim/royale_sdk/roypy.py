"""A stand-in for the royale SDK's Python binding ``roypy``, with the same interface.

This folder takes the place of the SDK's ``python`` folder on ``PYTHONPATH``: the
emulated rig (``launch.py graphs/hardware.yaml --emulate``) puts it there, so
``bubble_camera.royale`` imports it as it would import the SDK. What ``devices.royale``
uses of the SDK is here: ``CameraManager().getConnectedCameraList()`` and
``createCamera(id)``; a camera's ``initialize``, ``getUseCases``, ``setUseCase``,
``setExposureTime``, ``getLensParameters``, ``registerDataListener``,
``unregisterDataListener``, ``startCapture``, ``stopCapture``; listeners subclass
``IDepthDataListener`` and receive ``onNewData(data)`` on another thread, with
``data.npoints()`` a (height, width, 6) array (x, y, z, noise, gray, confidence) and
``data.timeStamp`` in microseconds. A method called on a camera that is gone raises
``RuntimeError`` (the binding's way to report a bad status).

Two kinds of camera:

* under an emulated rig (``$SOFTBUBBLE_EMULATED_RIG`` set) the manager lists the rig's
  plugged cameras, and each renders the simulated world (``sim.emulated_rig``);
* otherwise :func:`module` makes a ``roypy`` with cameras that deliver what a test
  hands to :meth:`Camera.emit`.
"""

from __future__ import annotations

import os
import threading
import types
from typing import Any

import numpy as np

PICO_FLEXX_USE_CASES = [
    "MODE_9_5FPS_2000", "MODE_9_10FPS_1000", "MODE_9_15FPS_700", "MODE_9_25FPS_450",
    "MODE_5_35FPS_600", "MODE_5_45FPS_500",
]  # fmt: skip
LENS = {"cx": 111.4, "cy": 86.2, "fx": 210.5, "fy": 210.9, "k1": 0.36, "k2": -4.4, "k3": 7.9,
        "p1": 0.0, "p2": 0.0}  # fmt: skip


class IDepthDataListener:
    def __init__(self) -> None:
        pass


class DepthData:
    def __init__(self, points: np.ndarray, stamp_us: int) -> None:
        self.height, self.width = points.shape[:2]
        self.timeStamp = stamp_us
        self._points = points

    def npoints(self) -> np.ndarray:
        return self._points


class Camera:
    """One camera (see the module docstring); ``emulator`` is a ``sim.emulated_rig``
    camera, or None for a camera fed by :meth:`emit`."""

    def __init__(self, camera_id: str, emulator: Any = None) -> None:
        self.camera_id = camera_id
        self.emulator = emulator
        self.use_case = ""
        self.exposure_us = 0
        self.listener: Any = None
        self.capturing = False

    def _check(self) -> None:
        if self.emulator is not None:
            from sim.emulated_rig import session

            if not session().plugged(self.emulator.device):
                raise RuntimeError("Device disconnected")

    def initialize(self) -> None:
        self._check()

    def getUseCases(self) -> list[str]:  # noqa: N802 (the SDK's names)
        return list(PICO_FLEXX_USE_CASES)

    def setUseCase(self, name: str) -> None:  # noqa: N802
        if name not in PICO_FLEXX_USE_CASES:
            raise RuntimeError("Use case not supported")
        self.use_case = name

    def setExposureTime(self, exposure_us: int) -> None:  # noqa: N802
        self.exposure_us = exposure_us

    def getLensParameters(self) -> dict[str, float]:  # noqa: N802
        if self.emulator is None:
            return dict(LENS)
        from sim.emulated_rig import PICO_FLEXX_LENS

        cam = self.emulator.camera()
        return {
            "fx": cam.fx_px,
            "fy": cam.fy_px,
            "cx": cam.cx_px,
            "cy": cam.cy_px,
            **PICO_FLEXX_LENS,
        }

    def registerDataListener(self, listener: Any) -> None:  # noqa: N802
        self.listener = listener

    def unregisterDataListener(self) -> None:  # noqa: N802
        self.listener = None

    def startCapture(self) -> None:  # noqa: N802
        self._check()
        self.capturing = True
        if self.emulator is not None:
            self.emulator.start(self.use_case, self._deliver)

    def stopCapture(self) -> None:  # noqa: N802
        self.capturing = False
        if self.emulator is not None:
            self.emulator.stop()
        self._check()

    def _deliver(self, points: np.ndarray, stamp_us: int) -> None:
        listener = self.listener
        if self.capturing and listener is not None:
            listener.onNewData(DepthData(points, stamp_us))

    def emit(self, points: np.ndarray, stamp_us: int) -> None:
        """Deliver one frame from another thread and wait until the listener returns."""
        thread = threading.Thread(target=self._deliver, args=(points, stamp_us))
        thread.start()
        thread.join(5)


_rig_cameras: dict[str, Camera] = {}


def _emulated() -> dict[str, Camera]:
    """The emulated rig's cameras that are plugged in, by id (made once per process)."""
    from geometry.gripper import SIDES
    from sim.emulated_rig import SESSION_ENV, CameraEmulator, session

    if not os.environ.get(SESSION_ENV):
        return {}  # the stand-in without an emulated rig: no camera is plugged in
    rig = session()
    if not _rig_cameras:
        for side in SIDES:
            spec = rig.rig.cameras[side]
            emulator = CameraEmulator(side, spec, f"{side}_camera")
            _rig_cameras[spec.camera_id] = Camera(spec.camera_id, emulator)
    return {cid: c for cid, c in _rig_cameras.items() if rig.plugged(c.emulator.device)}


class CameraManager:
    """Lists and opens the emulated rig's cameras (none without ``$SOFTBUBBLE_EMULATED_RIG``)."""

    def getConnectedCameraList(self) -> list[str]:  # noqa: N802
        return list(_emulated())

    def createCamera(self, camera_id: str) -> Camera:  # noqa: N802
        cameras = _emulated()
        if camera_id not in cameras:
            raise RuntimeError(f"Camera {camera_id} not found")
        return cameras[camera_id]


def module(*camera_ids: str) -> types.ModuleType:
    """A ``roypy`` module whose manager sees cameras fed by ``emit`` (``module.cameras``)."""
    mod = types.ModuleType("roypy")
    cameras = {cid: Camera(cid) for cid in camera_ids}

    class ManualCameraManager:
        def getConnectedCameraList(self) -> list[str]:  # noqa: N802
            return list(cameras)

        def createCamera(self, camera_id: str) -> Camera:  # noqa: N802
            return cameras[camera_id]

    mod.IDepthDataListener = IDepthDataListener  # type: ignore[attr-defined]
    mod.CameraManager = ManualCameraManager  # type: ignore[attr-defined]
    mod.cameras = cameras  # type: ignore[attr-defined]
    return mod
