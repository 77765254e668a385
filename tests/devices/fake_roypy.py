"""A stand-in for the royale SDK's ``roypy`` with the same interface (devices.royale's
docstring lists it), so ``bubble_camera.royale`` runs without the SDK. Frames are
delivered on another thread, as the SDK does."""

from __future__ import annotations

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
    def __init__(self, camera_id: str) -> None:
        self.camera_id = camera_id
        self.use_case = ""
        self.exposure_us = 0
        self.listener: Any = None
        self.capturing = False

    def initialize(self) -> None:
        pass

    def getUseCases(self) -> list[str]:  # noqa: N802 (the SDK's names)
        return list(PICO_FLEXX_USE_CASES)

    def setUseCase(self, name: str) -> None:  # noqa: N802
        if name not in PICO_FLEXX_USE_CASES:
            raise RuntimeError("Use case not supported")
        self.use_case = name

    def setExposureTime(self, exposure_us: int) -> None:  # noqa: N802
        self.exposure_us = exposure_us

    def getLensParameters(self) -> dict[str, float]:  # noqa: N802
        return dict(LENS)

    def registerDataListener(self, listener: Any) -> None:  # noqa: N802
        self.listener = listener

    def unregisterDataListener(self) -> None:  # noqa: N802
        self.listener = None

    def startCapture(self) -> None:  # noqa: N802
        self.capturing = True

    def stopCapture(self) -> None:  # noqa: N802
        self.capturing = False

    def emit(self, points: np.ndarray, stamp_us: int) -> None:
        """Deliver one frame from another thread and wait until the listener returns."""
        thread = threading.Thread(
            target=self.listener.onNewData, args=(DepthData(points, stamp_us),)
        )
        thread.start()
        thread.join(5)


def module(*camera_ids: str) -> types.ModuleType:
    """A ``roypy`` module whose manager sees cameras with these ids (``module.cameras``)."""
    mod = types.ModuleType("roypy")
    cameras = {cid: Camera(cid) for cid in camera_ids}

    class CameraManager:
        def getConnectedCameraList(self) -> list[str]:  # noqa: N802
            return list(cameras)

        def createCamera(self, camera_id: str) -> Camera:  # noqa: N802
            return cameras[camera_id]

    mod.IDepthDataListener = IDepthDataListener  # type: ignore[attr-defined]
    mod.CameraManager = CameraManager  # type: ignore[attr-defined]
    mod.cameras = cameras  # type: ignore[attr-defined]
    return mod
