"""Every message type of the pipeline, declared once. Units are in the field names.

Conventions (DESIGN.md): SI units; poses ``a_from_b`` as 4x4 float64 homogeneous
matrices; quaternions, where they appear, are ``(w, x, y, z)``; depth is float32
metres with NaN for invalid pixels; IR is uint16 amplitude; ``sensor`` is ``"left"``
or ``"right"``.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

from messages.base import Array, Header, Message

F32Image = Annotated[np.ndarray, Array("float32", (None, None))]
U16Image = Annotated[np.ndarray, Array("uint16", (None, None))]
U8Image = Annotated[np.ndarray, Array("uint8", (None, None))]
Pose4x4 = Annotated[np.ndarray, Array("float64", (4, 4))]


class ToFImage(Message):
    """One frame of a bubble's internal time-of-flight camera."""

    header: Header
    sensor: str
    depth_m: F32Image
    ir: U16Image
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float


class Pressure(Message):
    """A bubble's internal pressure, gauge (over ambient)."""

    header: Header
    sensor: str
    pressure_pa: float


class GripperState(Message):
    """Measured state of the parallel gripper (WSG 50 or its simulation)."""

    header: Header
    width_m: float
    speed_m_per_s: float
    force_n: float
    state: str = "idle"  # idle | moving | holding | fault


class GripperCommand(Message):
    """A command to the gripper: ``move``, ``grasp``, ``release``, ``stop`` or ``home``."""

    header: Header
    command: str
    width_m: float = 0.0
    speed_m_per_s: float = 0.05
    force_n: float = 20.0


class GraspState(Message):
    """Stable-grasp detection from the pressure rise and finger speed (grasp monitor)."""

    header: Header
    stable: bool
    event: str = ""  # "" | "stable" | "released"
    pressure_rise_left_pa: float = 0.0
    pressure_rise_right_pa: float = 0.0
    finger_speed_m_per_s: float = 0.0


class ContactPatch(Message):
    """The concatenated grasp cloud in the tool frame; ``bubble`` is 0 (left) or 1 (right)."""

    header: Header
    points_in_tool: Annotated[np.ndarray, Array("float32", (None, 3))]
    bubble: Annotated[np.ndarray, Array("uint8", (None,))]


class MaskImage(Message):
    """A per-pixel mask of one sensor (255 = selected)."""

    header: Header
    sensor: str
    mask: U8Image


class PoseEstimate(Message):
    """In-hand object pose and how the solver got it."""

    header: Header
    tool_from_object: Pose4x4
    residual_rms_m: float
    cost: float
    iterations: int
    status: str  # "ok" | "recovered" | "no_patch" | "failed" | ...
    solve_secs: float
    points_used: int
    solver: str = ""
    # Which of (tx, ty, tz, rx, ry, rz) in the object frame the patch constrains.
    observable: list[bool] = []
    # Why the status is not "ok" (empty when it is).
    message: str = ""
    # The depth noise the acceptance test used (estimated from the patch), metres.
    noise_m: float = 0.0
    # Dimensions fitted beside the pose (``fit_dims``); 0 when not fitted.
    fitted_radius_m: float = 0.0
    fitted_height_m: float = 0.0


class ShearEstimate(Message):
    """Shear of one bubble against its stable-grasp reference."""

    header: Header
    sensor: str
    shear_px: Annotated[np.ndarray, Array("float64", (2,))]
    magnitude_px: float
    direction: Annotated[np.ndarray, Array("float64", (2,))]
    direction_defined: bool
    shear_mm: Annotated[np.ndarray, Array("float64", (2,))]
    torsion_rad: float = 0.0
    has_reference: bool = True


class OverlayImage(Message):
    """An 8-bit BGR image for the viewer (e.g. IR with the flow field drawn on it)."""

    header: Header
    sensor: str
    image: Annotated[np.ndarray, Array("uint8", (None, None, 3))]


class ClassProbabilities(Message):
    """The classifier's output for one stable grasp frame."""

    header: Header
    classes: list[str]
    probabilities: Annotated[np.ndarray, Array("float32", (None,))]
    best: str = ""


class TaskEvent(Message):
    """Something a task supervisor decided or observed."""

    header: Header
    task: str
    event: str
    detail: str = ""


class GroundTruth(Message):
    """What the simulator knows: true pose, contact and shear (for scoring only)."""

    header: Header
    tool_from_object: Pose4x4
    object_class: str
    in_contact: bool
    shear_left_mm: Annotated[np.ndarray, Array("float64", (2,))]
    shear_right_mm: Annotated[np.ndarray, Array("float64", (2,))]
    noise_seed: int  # the scene's seed: it draws the sensors' noise in this frame


class Tick(Message):
    """A plain counter message (synthetic graphs, tests, benchmarks)."""

    header: Header
    value: float = 0.0
    payload: Annotated[np.ndarray, Array("uint8", (None,))] = msgspec.field(
        default_factory=lambda: np.zeros(0, np.uint8)
    )
