"""``supervisor.stacking`` (paper, task 3: blind stacking by shear).

Closes the gripper, waits for a stable grasp, and then, while the arm lowers the object
onto a surface or another object of unknown height, watches both bubbles' shear: the
touch pushes the object up in the hand, the membranes shear, and when the shear
magnitude stays at or above ``touch_shear_px`` for ``confirm_frames`` frames it opens
the gripper. It knows nothing of the geometry: not the support's height, not the
object's size.

After the release it waits (at most ``placement_wait_secs`` of data time) for the
world's truth (``placement``: placed, with the gap it fell and its tilt, or dropped),
publishes a ``summary`` event (JSON) and stops the graph; its verdict (exit code 1)
says the object was dropped. Without a ``placement`` input (hardware) the outcome is
unknown and the verdict 0.

Ports:
    inputs: ``grasp`` (GraspState), ``shear`` (ShearEstimate), ``placement``
        (messages.sim.PlacementTruth from ``world.sim``, optional).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent, task ``stacking``).
"""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta

from messages import GraspState, ShearEstimate
from messages.sim import PlacementTruth
from messages.tasks import PlacementSummary
from nodes.supervisor.base import SingleGraspTask, TaskParams
from nodes.supervisor.handover import ShearWatch, describe_shear
from runtime.registry import register


class StackingParams(TaskParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    touch_shear_px: Annotated[float, Meta(gt=0)] = 1.0
    confirm_frames: Annotated[int, Meta(ge=1)] = 2
    placement_wait_secs: Annotated[float, Meta(ge=0)] = 1.0
    grasp_speed_m_per_s: float = 0.1


@register("supervisor.stacking")
class StackingSupervisor(SingleGraspTask):
    """Set the held object down where a touch shears the bubbles (module docstring)."""

    Params = StackingParams
    inputs = {"grasp": GraspState, "shear": ShearEstimate, "placement": PlacementTruth}
    optional_inputs = frozenset({"placement"})
    task = "stacking"

    def setup(self) -> None:
        super().setup()
        self.watch = ShearWatch(self.params.touch_shear_px, self.params.confirm_frames)
        self.placement: PlacementTruth | None = None
        self.released_nanos: int | None = None

    def on_shear(self, msg: ShearEstimate) -> None:
        if self.state == "holding" and self.watch.update(msg):
            self.release(f"touch {describe_shear(msg)}")

    def on_placement(self, msg: PlacementTruth) -> None:
        self.placement = msg
        if self.released_nanos is not None:
            self._summary()

    def on_released(self) -> None:
        self.released_nanos = self.msg_nanos
        self.state = "placing"
        if self.placement is not None:
            self._summary()

    def advance(self, elapsed_secs: float) -> None:
        super().advance(elapsed_secs)
        if (
            self.state == "placing"
            and self.released_nanos is not None
            and self.now_nanos - self.released_nanos > self.params.placement_wait_secs * 1e9
        ):
            self._summary()

    def _summary(self) -> None:
        release_secs = round(((self.release_sent_nanos or 0) - (self.first_nanos or 0)) / 1e9, 4)
        if self.placement is None:
            summary = PlacementSummary(release_secs=release_secs, outcome="unknown")
            outcome, failed = "unknown (no placement truth)", False
        else:
            truth = self.placement
            event: Literal["placed", "dropped"] = "placed" if truth.placed else "dropped"
            summary = PlacementSummary(
                release_secs=release_secs,
                outcome=event,
                t_secs=round(truth.t_secs, 4),
                touch_secs=None if truth.touch_secs is None else round(truth.touch_secs, 4),
                gap_mm=round(truth.gap_m * 1000, 3),
                push_mm=round(truth.push_m * 1000, 3),
                tilt_deg=round(truth.tilt_deg, 3),
            )
            failed = not truth.placed
            outcome = (
                f"{event}: gap {truth.gap_m * 1000:.1f} mm, tilt {truth.tilt_deg:.1f} deg, "
                f"{truth.push_m * 1000:.1f} mm pressed past contact"
            )
        self.event("summary", data=summary)
        self.finish(f"{self.task}: {outcome}", exit_code=1 if failed else 0)
