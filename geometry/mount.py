"""Where a camera frame was taken: the camera's pose in the tool frame at the frame's stamp.

A bubble camera is fixed in its finger (``finger_from_sensor``: the rig's calibration, or
the CAD value of ``geometry.gripper`` when there is none) and the finger moves with the
gripper's opening. So a frame's pose in the tool frame is::

    tool_from_sensor = tool_from_finger(side, width_m at the frame's stamp) @ finger_from_sensor

:class:`CameraMounts` holds both cameras' mounts; :class:`OpeningHistory` keeps the
gripper's measured openings and answers the opening at a stamp (linear between the two
states around it, the nearest one outside them). A camera driver places each frame with
them (``bubble_camera.royale``), and the simulator with its scene's geometry, so every
``ToFImage`` carries its ``tool_from_sensor`` and every reader (contact patch, shear
tracker, viewers, a replayed bag) uses the pose the frame was taken at.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.gripper import DEFAULT_GRIPPER, SIDES, GripperGeometry


def check_pose(name: str, pose: Any) -> np.ndarray:
    """``pose`` as a 4x4 float64 rigid transform, or ``ValueError`` naming ``name``."""
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4) or not np.isfinite(arr).all():
        raise ValueError(f"`{name}` must be a finite 4x4 pose, got shape {arr.shape}")
    rot = arr[:3, :3]
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError(f"`{name}` must have a proper rotation in its upper-left 3x3")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"`{name}` must end with the row [0, 0, 0, 1], got {arr[3].tolist()}")
    return arr


@dataclass(frozen=True)
class CameraMounts:
    """Each camera's pose in its finger, and the gripper geometry that moves the fingers.

    ``finger_from_sensor`` maps ``left``/``right`` to 4x4 poses; a side that is missing
    uses the CAD mount of ``geometry``.
    """

    finger_from_sensor: Mapping[str, np.ndarray] = field(default_factory=dict)
    geometry: GripperGeometry = DEFAULT_GRIPPER

    def __post_init__(self) -> None:
        for side, pose in self.finger_from_sensor.items():
            if side not in SIDES:
                raise ValueError(f"mount side must be 'left' or 'right', got {side!r}")
            check_pose(f"{side}.finger_from_sensor", pose)

    def mount(self, side: str) -> np.ndarray:
        """``side``'s camera in its finger frame."""
        pose = self.finger_from_sensor.get(side)
        out: np.ndarray = np.array(
            self.geometry.finger_from_sensor() if pose is None else pose, dtype=np.float64
        )
        return out

    def tool_from_sensor(self, side: str, width_m: float) -> np.ndarray:
        """``side``'s camera in the tool frame at opening ``width_m``."""
        pose: np.ndarray = self.geometry.tool_from_finger(side, width_m) @ self.mount(side)
        return pose


CAD_MOUNTS = CameraMounts()


class OpeningHistory:
    """The gripper's measured openings by stamp (the newest ``size`` kept)."""

    def __init__(self, size: int = 256) -> None:
        self._stamps: deque[int] = deque(maxlen=size)
        self._widths: deque[float] = deque(maxlen=size)

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_nanos(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def add(self, stamp_nanos: int, width_m: float) -> None:
        """One measured opening; a state older than the newest is dropped (out of order)."""
        if self._stamps and stamp_nanos < self._stamps[-1]:
            return
        self._stamps.append(int(stamp_nanos))
        self._widths.append(float(width_m))

    def width_at(self, stamp_nanos: int) -> float | None:
        """The opening at ``stamp_nanos``: interpolated between the states around it, the
        oldest or newest state outside them; None before any state."""
        if not self._stamps:
            return None
        stamps = list(self._stamps)
        i = bisect.bisect_left(stamps, stamp_nanos)
        if i == 0:
            return self._widths[0]
        if i == len(stamps):
            return self._widths[-1]
        t0, t1 = stamps[i - 1], stamps[i]
        w0, w1 = self._widths[i - 1], self._widths[i]
        if t1 == t0:
            return w1
        return w0 + (w1 - w0) * (stamp_nanos - t0) / (t1 - t0)
