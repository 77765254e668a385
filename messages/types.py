"""Every message type of the pipeline, declared once. Units are in the field names.

Conventions (docs/design.md): SI units; poses ``a_from_b`` as 4x4 float64 homogeneous
matrices; quaternions, where they appear, are ``(w, x, y, z)``; depth is float32
metres with NaN for invalid pixels; IR is uint16 amplitude; ``sensor`` is ``"left"``
or ``"right"``.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import msgspec
import numpy as np

from messages.base import Array, Header, Message
from messages.tasks import TaskData, TaskEventName

Side = Literal["left", "right"]
"""``sensor`` of a bubble's camera or pressure sensor: which bubble."""

GripperStatus = Literal["idle", "moving", "holding", "fault"]
"""``GripperState.state``: at rest, fingers moving, holding a part (grasp force reached), or
a fault the gripper reports."""

GripperAction = Literal["move", "grasp", "release", "stop", "home"]
"""``GripperCommand.command``: move to ``width_m``, grasp (close to ``width_m`` with
``force_n``), release (open), stop where it is, home (find its limits)."""

GraspEvent = Literal["", "stable", "released"]
"""``GraspState.event``: ``""`` (no change), ``"stable"`` (a stable grasp began),
``"released"`` (it ended)."""

PoseStatus = Literal["ok", "recovered", "suspect", "no_patch", "failed"]
"""``PoseEstimate.status``: ``ok`` (the fit from the prior converged and fits),
``recovered`` (a restart from other seeds fitted after the prior's fit did not),
``suspect`` (no start fitted well; the lowest-cost pose is returned), ``no_patch``
(too few contact points to fit), ``failed`` (the solver gave no finite pose)."""

F32Image = Annotated[np.ndarray, Array("float32", (None, None))]
U16Image = Annotated[np.ndarray, Array("uint16", (None, None))]
U8Image = Annotated[np.ndarray, Array("uint8", (None, None))]
Pose4x4 = Annotated[np.ndarray, Array("float64", (4, 4))]


def _unknown_pose() -> np.ndarray:
    return np.zeros((4, 4))


def pose_is_known(pose: np.ndarray) -> bool:
    """Whether a 4x4 pose field holds a pose (the all-zero matrix means "not known")."""
    return bool(pose.shape == (4, 4) and pose[3, 3] == 1.0 and np.isfinite(pose).all())


class ToFImage(Message):
    """One frame of a bubble's internal time-of-flight camera.

    ``tool_from_sensor`` is the camera's pose in the gripper's tool frame when the frame
    was taken (it moves with the opening): the geometry the frame's own scene or
    calibration uses, so perception never assumes a default mount. All zeros when the
    source does not know it; nodes that need it refuse such frames.
    """

    header: Header
    sensor: Side
    depth_m: F32Image
    ir: U16Image
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    tool_from_sensor: Pose4x4 = msgspec.field(default_factory=_unknown_pose)

    finite_fields: ClassVar[tuple[str, ...]] = ("depth_m", "fx_px", "fy_px", "cx_px", "cy_px")
    nan_marks_invalid: ClassVar[frozenset[str]] = frozenset({"depth_m"})


class Pressure(Message):
    """A bubble's internal pressure, gauge (over ambient)."""

    header: Header
    sensor: Side
    pressure_pa: float

    finite_fields: ClassVar[tuple[str, ...]] = ("pressure_pa",)


class GripperState(Message):
    """Measured state of the parallel gripper (WSG 50 or its simulation)."""

    header: Header
    width_m: float
    speed_m_per_s: float
    force_n: float
    state: GripperStatus = "idle"

    finite_fields: ClassVar[tuple[str, ...]] = ("width_m", "speed_m_per_s", "force_n")


class GripperCommand(Message):
    """A command to the gripper: ``move``, ``grasp``, ``release``, ``stop`` or ``home``."""

    header: Header
    command: GripperAction
    width_m: float = 0.0
    speed_m_per_s: float = 0.05
    force_n: float = 20.0


class GraspState(Message):
    """Stable-grasp detection from the pressure rise and finger speed (grasp monitor)."""

    header: Header
    stable: bool
    event: GraspEvent = ""
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
    sensor: Side
    mask: U8Image


class PoseEstimate(Message):
    """In-hand object pose, how the solver got it, and how sure it is.

    ``status`` ``ok`` (or ``recovered``): every direction the patch observes is
    determined to the estimator's tolerance (2 degrees, 2 mm by default) at 95%
    confidence, and nothing else that fits as well differs along them. ``suspect``:
    not so; ``message`` says why. The uncertainty is in the object frame, as a left
    twist ``(tx, ty, tz, rx, ry, rz)``: ``observable`` says which directions the patch
    constrains at all (the others are not held against the answer: a cylinder's yaw,
    its slide along its axis), ``covariance`` and the standard deviations cover the
    observable ones (zero along the others), and ``alternatives`` describes other
    minima that agree with this one on every observable direction (a bottle end over
    end).
    """

    header: Header
    tool_from_object: Pose4x4
    residual_rms_m: float
    cost: float  # the solver's objective: the sum of squared residuals, m^2
    iterations: int
    status: PoseStatus
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
    # Covariance of the left twist (tx, ty, tz in m; rx, ry, rz in rad), object frame;
    # zero along unobservable directions and when not computed (no_patch, failed).
    covariance: Annotated[np.ndarray, Array("float64", (6, 6))] = msgspec.field(
        default_factory=lambda: np.zeros((6, 6))
    )
    # Standard deviations along the object's x, y, z: of its origin and of rotations about them.
    translation_std_m: list[float] = []
    rotation_std_deg: list[float] = []
    # The largest rotation and displacement of the origin within the 95% region.
    region95_deg: float = 0.0
    region95_m: float = 0.0
    # Other minima that fit as well and agree on every observable direction, described.
    alternatives: str = ""

    wall_clock_fields: ClassVar[tuple[str, ...]] = ("solve_secs",)


class ShearEstimate(Message):
    """Shear of one bubble against its stable-grasp reference.

    ``shear_px`` is the mean image flow (pixels), ``direction`` its unit vector (zero
    when ``direction_defined`` is false), ``shear_m`` the mean tangential membrane shift
    in metres along the tool's (y, z) or the membrane's plane, ``torsion_rad`` the
    rotation about the contact normal.
    """

    header: Header
    sensor: Side
    shear_px: Annotated[np.ndarray, Array("float64", (2,))]
    magnitude_px: float
    direction: Annotated[np.ndarray, Array("float64", (2,))]
    direction_defined: bool
    shear_m: Annotated[np.ndarray, Array("float64", (2,))]
    torsion_rad: float = 0.0
    has_reference: bool = True


class OverlayImage(Message):
    """An 8-bit BGR image for the viewer (e.g. IR with the flow field drawn on it)."""

    header: Header
    sensor: Side
    image: Annotated[np.ndarray, Array("uint8", (None, None, 3))]


class ClassProbabilities(Message):
    """The classifier's output for one stable grasp frame."""

    header: Header
    classes: list[str]
    probabilities: Annotated[np.ndarray, Array("float32", (None,))]
    best: str = ""


class TaskEvent(Message):
    """Something a task supervisor decided or observed: ``detail`` says it for people,
    ``data`` holds its figures typed (``messages.tasks``), ``None`` where it has none."""

    header: Header
    task: str
    event: TaskEventName
    detail: str = ""
    data: TaskData | None = None


class GroundTruth(Message):
    """What the simulator knows: true pose, contact and shear (for scoring only)."""

    header: Header
    tool_from_object: Pose4x4
    object_class: str
    in_contact: bool
    shear_left_m: Annotated[np.ndarray, Array("float64", (2,))]  # tool (y, z)
    shear_right_m: Annotated[np.ndarray, Array("float64", (2,))]
    noise_seed: int  # the scene's seed: it draws the sensors' noise in this frame


class Tick(Message):
    """A plain counter message (synthetic graphs, tests, benchmarks)."""

    header: Header
    value: float = 0.0
    payload: Annotated[np.ndarray, Array("uint8", (None,))] = msgspec.field(
        default_factory=lambda: np.zeros(0, np.uint8)
    )
