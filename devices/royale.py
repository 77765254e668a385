"""A PMD pico flexx through the royale SDK's Python binding, ``roypy``.

``roypy`` ships with the royale SDK (not on PyPI) and is imported only when a camera is
opened, so everything else runs without it. The interface used, as the SDK's binding
declares it: ``roypy.CameraManager()`` with ``getConnectedCameraList()`` and
``createCamera(id)``; a camera's ``initialize()``, ``getUseCases()``, ``setUseCase(name)``,
``setExposureTime(microseconds)``, ``getLensParameters()`` (a dict with ``fx``, ``fy``,
``cx``, ``cy`` and the distortion ``k1``, ``k2``, ``k3``, ``p1``, ``p2``),
``registerDataListener(listener)``, ``unregisterDataListener()``, ``startCapture()`` and
``stopCapture()``; a listener subclasses ``roypy.IDepthDataListener`` and receives each
frame in ``onNewData(data)``, where ``data.npoints()`` is a (height, width, 6) array of
x, y, z (metres), noise (metres), gray value and depth confidence per pixel.

A pixel is invalid when its confidence is 0 or its noise is over ``max_noise_m``
(0.07 m, as the SDK's own driver decides); its depth becomes NaN. The depth image is z
along the optical axis; ``ToFImage`` carries the pinhole part of the camera's own lens
parameters (its distortion is not carried: the SDK's 3D points are undistorted, the
pixel grid is not).
"""

from __future__ import annotations

import importlib
import queue
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from devices.base import Device
from messages.errors import DeviceError

ROYPY_HINT = (
    "the royale SDK's Python binding `roypy` is not importable: install the royale SDK"
    " for the pico flexx from pmdtec (https://pmdtec.com), and put the SDK's `python`"
    " folder (the one holding roypy.py and the compiled _roypy module) on PYTHONPATH,"
    " with the SDK's `bin` folder on LD_LIBRARY_PATH"
)
MAX_NOISE_M = 0.07


def import_roypy() -> ModuleType:
    """The ``roypy`` module, or a :class:`DeviceError` saying what to install and where."""
    try:
        return importlib.import_module("roypy")
    except ImportError as err:
        raise DeviceError(f"{ROYPY_HINT} ({err})") from err


@dataclass(frozen=True)
class Intrinsics:
    """The pinhole part of the camera's lens parameters, in pixels."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float


def intrinsics(lens: Mapping[str, float]) -> Intrinsics:
    """The intrinsics in a ``getLensParameters()`` dict; a missing key is an error."""
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in lens]
    if missing:
        raise DeviceError(f"royale: lens parameters lack {missing} (got {sorted(lens)})")
    values = Intrinsics(float(lens["fx"]), float(lens["fy"]), float(lens["cx"]), float(lens["cy"]))
    if not (values.fx_px > 0 and values.fy_px > 0):
        raise DeviceError(f"royale: focal lengths must be > 0, got {values}")
    return values


def convert(
    points: np.ndarray, *, max_noise_m: float = MAX_NOISE_M
) -> tuple[np.ndarray, np.ndarray]:
    """``(depth_m float32 with NaN where invalid, ir uint16)`` from ``npoints()``'s array."""
    if points.ndim != 3 or points.shape[2] != 6:
        raise DeviceError(f"royale: expected (height, width, 6) points, got shape {points.shape}")
    z, noise, gray, confidence = points[..., 2], points[..., 3], points[..., 4], points[..., 5]
    invalid = (confidence <= 0) | (noise > max_noise_m) | ~np.isfinite(z) | (z <= 0)
    depth = np.where(invalid, np.nan, z).astype(np.float32)
    ir = np.clip(np.nan_to_num(gray), 0, 65535).astype(np.uint16)
    return depth, ir


@dataclass(frozen=True)
class Frame:
    """One frame's arrays (copied out of the SDK's callback) and its stamp."""

    depth_m: np.ndarray
    ir: np.ndarray
    stamp_nanos: int


class RoyaleCamera(Device):
    """One camera: opened by id with a use case; frames arrive on :attr:`frames`."""

    def __init__(
        self,
        camera_id: str = "",
        *,
        use_case: str,
        exposure_us: int = 0,
        max_noise_m: float = MAX_NOISE_M,
    ) -> None:
        self.camera_id = camera_id
        self.use_case = use_case
        self.exposure_us = exposure_us
        self.max_noise_m = max_noise_m
        self.frames: queue.Queue[Frame] = queue.Queue(maxsize=4)
        self.dropped = 0
        self.intrinsics: Intrinsics | None = None
        self._camera: Any = None
        self._listener: Any = None
        self._lock = threading.Lock()

    @property
    def is_connected(self) -> bool:
        return self._camera is not None

    def connect(self) -> None:
        """Import roypy, open the camera, set use case and exposure, start capturing."""
        roypy = import_roypy()
        manager = roypy.CameraManager()
        connected = list(manager.getConnectedCameraList())
        if self.camera_id:
            chosen = self.camera_id if self.camera_id in connected else None
        else:
            chosen = connected[0] if len(connected) == 1 else None
        if chosen is None:
            need = (
                f"camera {self.camera_id!r}" if self.camera_id else "exactly one camera (or an id)"
            )
            raise DeviceError(
                f"royale: need {need}; connected: {connected or 'none'} (check the USB cable;"
                " the SDK's royaleviewer lists cameras too)"
            )
        camera = manager.createCamera(chosen)
        try:
            camera.initialize()
            use_cases = list(camera.getUseCases())
            if self.use_case not in use_cases:
                raise DeviceError(
                    f"royale: camera {chosen!r} has no use case {self.use_case!r}; it offers {use_cases}"
                )
            camera.setUseCase(self.use_case)
            if self.exposure_us > 0:
                camera.setExposureTime(self.exposure_us)
            self.intrinsics = intrinsics(dict(camera.getLensParameters()))
            self._listener = _listener_class(roypy)(self._on_points)
            camera.registerDataListener(self._listener)
            camera.startCapture()
        except RuntimeError as err:  # the binding raises RuntimeError for a bad status
            raise DeviceError(f"royale: camera {chosen!r}: {err}") from err
        self._camera = camera
        self.camera_id = chosen

    def disconnect(self) -> None:
        camera, self._camera = self._camera, None
        if camera is None:
            return
        try:
            camera.stopCapture()
            camera.unregisterDataListener()
        except RuntimeError:
            pass  # unplugged: nothing to stop

    def _on_points(self, points: np.ndarray, stamp_nanos: int) -> None:
        """Called on the SDK's thread: convert now (the data lives only in the callback)."""
        depth, ir = convert(points, max_noise_m=self.max_noise_m)
        frame = Frame(depth, ir, stamp_nanos)
        with self._lock:
            if self.frames.full():
                self.frames.get_nowait()  # keep the newest: a late frame is worth less
                self.dropped += 1
            self.frames.put_nowait(frame)


def _listener_class(roypy: ModuleType) -> type:
    """A data listener deriving from the binding's ``IDepthDataListener``."""

    class Listener(roypy.IDepthDataListener):  # type: ignore[misc, name-defined]
        def __init__(self, callback: Any) -> None:
            super().__init__()
            self.callback = callback

        def onNewData(self, data: Any) -> None:  # noqa: N802 (the SDK's name)
            # royale stamps frames in microseconds since the epoch.
            self.callback(np.array(data.npoints(), dtype=np.float64), int(data.timeStamp) * 1000)

    return Listener
