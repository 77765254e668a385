"""``supervisor.handover`` (paper, task 3: shear-based release and handover).

Closes the gripper on the object, waits for the grasp monitor's stable grasp, then
decides, for as long as it holds the object, between letting go and holding on:

* **Release on a pull.** With the ``wrench`` input wired (and ``release_on: force``,
  the default; ``shear`` keeps the paper's rule below): when the bubbles' force on
  the object has changed since the stable grasp by ``release_force_n`` or more, in a
  direction other than straight up against ``gravity_in_tool`` (a person pulls), for
  ``force_confirm_frames`` estimates (``perception.force.reflex.PullWatch``). The
  baseline is the first estimate stamped at or after the stable grasp with both bubbles
  in contact, and only such estimates count (a bubble that missed its free reference
  sees no contact: half the grasp's force is no pull). Until then, while the newest
  such estimate is more than ``force_max_lag_secs`` older than the shear's (the
  ``wrench`` node behind on a loaded machine), and without ``wrench``, the paper's rule: when a bubble's shear magnitude (``ShearEstimate.magnitude_px``,
  the mean displacement of the membrane against the stable-grasp reference) stays at
  or above ``release_shear_px`` for ``confirm_frames`` frames.
* **Squeeze on slip.** With the ``slip`` input wired and ``reflex`` on: a slip onset
  that is not a pull (the object is getting heavier) raises the grip force
  (``perception.force.reflex.GripReflex``) up to ``max_grip_force_n``.

It reports the pull's direction with the release, and ends the graph once the grasp is
released, or at ``timeout_secs``.

Ports:
    inputs: ``grasp`` (GraspState); ``shear`` (ShearEstimate); ``pose`` (PoseEstimate,
        optional: the last estimate is reported with each event); ``wrench``
        (WrenchEstimate, optional); ``slip`` (SlipState, optional).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent, task ``handover``).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from msgspec import Meta

from devices.wsg50 import MAX_FORCE_N
from messages import GraspState, PoseEstimate, ShearEstimate
from messages.force import SlipState, WrenchEstimate
from nodes.supervisor.base import SingleGraspTask, TaskParams
from perception.force.reflex import GripReflex, PullWatch, ReflexParams
from runtime.registry import register


class HandoverParams(TaskParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The release rule (``release_on``: force, with ``wrench`` wired, or shear) and the
    slip reflex."""

    release_on: Literal["force", "shear"] = "force"
    release_shear_px: Annotated[float, Meta(gt=0)] = 1.5
    confirm_frames: Annotated[int, Meta(ge=1)] = 3
    release_force_n: Annotated[float, Meta(gt=0)] = 0.6
    force_confirm_frames: Annotated[int, Meta(ge=1)] = 2
    force_max_lag_secs: Annotated[float, Meta(gt=0)] = 0.2
    gravity_in_tool: tuple[float, float, float] = (0.0, -1.0, 0.0)
    reflex: bool = True
    max_grip_force_n: Annotated[
        float,
        Meta(gt=0, le=MAX_FORCE_N, description="the reflex's bound on the grip force"),
    ] = 40.0
    friction: Annotated[float, Meta(gt=0)] = 0.8


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
    """Release the object on a pull, squeeze it on slip (see the module docstring)."""

    Params = HandoverParams
    inputs = {
        "grasp": GraspState,
        "shear": ShearEstimate,
        "pose": PoseEstimate,
        "wrench": WrenchEstimate,
        "slip": SlipState,
    }
    optional_inputs = frozenset({"pose", "wrench", "slip"})
    # A release (shear, wrench) and a squeeze (slip) answer frames that reach the task by
    # paths of different lengths: taken in stamp order, live as in a replay. The pose is
    # for information only and goes straight through. On a tie (one camera frame) the
    # longer paths come first, so no message waits for the next frame of a slow path.
    ordered_inputs = ("grasp", "slip", "wrench", "shear")
    # Live, the release waits only for what its rules read: the shear rule for the grasp's
    # state, the force rule for that and the shear (its stand-in). Neither waits for the
    # slip, the longest path (camera -> wrench -> slip): a slip onset stamped before a
    # release but arriving after it finds the grip let go and is not answered (in
    # lockstep, and whenever the slip path keeps up, it squeezes first). A slip onset
    # waits for every other input: it reads the force and whether a pull is building.
    order_waits = {"grasp": ("shear",), "shear": ("grasp",), "wrench": ("grasp", "shear")}
    task = "handover"

    def setup(self) -> None:
        super().setup()
        p = self.params
        self.watch = ShearWatch(p.release_shear_px, p.confirm_frames)
        self.pull = PullWatch(p.release_force_n, p.force_confirm_frames, p.gravity_in_tool)
        self.reflex = GripReflex(
            ReflexParams(max_force_n=p.max_grip_force_n), p.grasp_force_n, p.friction
        )
        self.uses_force = False
        self.object_force_n: np.ndarray | None = None
        self.stable_stamp_nanos: int | None = None
        self.wrench_nanos = 0  # the newest estimate the force rule counted

    def on_grasp(self, msg: GraspState) -> None:
        if msg.event == "stable" and self.state == "grasping":
            self.stable_stamp_nanos = msg.header.stamp_nanos
        super().on_grasp(msg)

    def on_shear(self, msg: ShearEstimate) -> None:
        if self.state != "holding":
            return
        lag = (msg.header.stamp_nanos - self.wrench_nanos) / 1e9
        if self.uses_force and lag <= self.params.force_max_lag_secs:
            return  # the force rule, current, decides alone
        if self.watch.update(msg):
            self.release(f"pull {describe_shear(msg)}")

    def on_wrench(self, msg: WrenchEstimate) -> None:
        self.object_force_n = msg.object_force_n
        if self.params.release_on != "force" or self.state != "holding":
            return
        # Only the grasp's force counts: both bubbles in contact (a bubble without its
        # free reference, or whose frame was dropped, sees none: half the grasp's force
        # is no pull), measured at or after the stable grasp (an estimate from the
        # closing, still in flight when the grasp turned stable, is no baseline). Until
        # such an estimate comes the shear rule stands in.
        stable = self.stable_stamp_nanos
        if not all(msg.in_contact) or (stable is not None and msg.header.stamp_nanos < stable):
            return
        self.wrench_nanos = max(self.wrench_nanos, msg.header.stamp_nanos)
        if not self.uses_force:
            self.uses_force = True
            self.pull.start(msg.object_force_n)
            return
        if self.pull.update(msg.object_force_n):
            change = self.pull.change_n
            self.release(
                f"pull of {np.linalg.norm(change):.2f} N along tool"
                f" ({change[0]:.2f}, {change[1]:.2f}, {change[2]:.2f})"
            )

    def on_slip(self, msg: SlipState) -> None:
        if self.state != "holding" or not msg.onset or not self.params.reflex:
            return
        if self.stable_stamp_nanos is not None and msg.header.stamp_nanos < self.stable_stamp_nanos:
            return  # from the closing: the grasp, handed over first, is no longer waited for
        if self.pull.count > 0:
            return  # a pull is building: the release, not a squeeze, answers it
        load = 0.0 if self.object_force_n is None else float(np.hypot(*self.object_force_n[1:]))
        force = self.reflex.on_slip(msg.header.stamp_nanos / 1e9, load)
        if force is None:
            return
        self.command("grasp", self.params.grasp_width_m, force_n=force)
        self.event(
            "squeeze",
            f"{msg.sensor} bubble slips ({msg.onset}, use {msg.use:.2f}); grip {force:.1f} N",
        )
