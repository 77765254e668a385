"""``supervisor.handover`` (paper, task 3: shear-based release and handover).

Closes the gripper on the object, waits for the grasp monitor's stable grasp, then
watches both bubbles' shear; when the shear magnitude (the mean displacement per pixel
of the membrane against the stable-grasp reference, ``ShearEstimate.magnitude_px``)
stays above ``release_shear_px`` for ``confirm_frames`` frames (someone pulls), it opens
the gripper and reports the pull direction. It ends the graph once the grasp is
released, or at ``timeout_secs``.

Ports:
    inputs: ``grasp`` (GraspState); ``shear`` (ShearEstimate); ``pose`` (PoseEstimate,
        optional: the last estimate is reported with each event).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent, task ``handover``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from messages import GraspState, PoseEstimate, ShearEstimate
from nodes.supervisor.base import SingleGraspTask, TaskParams
from runtime.registry import register


@dataclass(frozen=True, kw_only=True)
class HandoverParams(TaskParams):
    release_shear_px: float = 1.5
    confirm_frames: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.release_shear_px > 0:
            raise ValueError(f"`release_shear_px` must be > 0, got {self.release_shear_px!r}")
        if self.confirm_frames < 1:
            raise ValueError(f"`confirm_frames` must be >= 1, got {self.confirm_frames!r}")


class ShearWatch:
    """Counts consecutive frames per bubble whose shear stays at or above a threshold."""

    def __init__(self, threshold_px: float, confirm_frames: int) -> None:
        self.threshold_px = threshold_px
        self.confirm_frames = confirm_frames
        self.above: dict[str, int] = {}

    def update(self, msg: ShearEstimate) -> bool:
        """True once ``msg``'s bubble has been sheared for ``confirm_frames`` frames."""
        if not msg.has_reference:
            return False
        sheared = msg.direction_defined and msg.magnitude_px >= self.threshold_px
        self.above[msg.sensor] = self.above.get(msg.sensor, 0) + 1 if sheared else 0
        return self.above[msg.sensor] >= self.confirm_frames


def describe_shear(msg: ShearEstimate) -> str:
    """``on the left bubble: 2.10 px at 90 deg (0.41 mm)``."""
    angle = float(np.degrees(np.arctan2(msg.direction[1], msg.direction[0])))
    return (
        f"on the {msg.sensor} bubble: {msg.magnitude_px:.2f} px at {angle:.0f} deg "
        f"({np.linalg.norm(msg.shear_m) * 1000.0:.2f} mm)"
    )


@register("supervisor.handover")
class HandoverSupervisor(SingleGraspTask):
    """Release the object when a pull shears the bubbles (see the module docstring)."""

    Params = HandoverParams
    inputs = {"grasp": GraspState, "shear": ShearEstimate, "pose": PoseEstimate}
    optional_inputs = frozenset({"pose"})
    task = "handover"

    def setup(self) -> None:
        super().setup()
        self.watch = ShearWatch(self.params.release_shear_px, self.params.confirm_frames)

    def on_shear(self, msg: ShearEstimate) -> None:
        if self.state != "holding":
            return
        if self.watch.update(msg):
            self.release(f"pull {describe_shear(msg)}")
