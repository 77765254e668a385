"""``supervisor.antagonism`` (paper, task 2: pose tracking under antagonism).

Closes the gripper on the object, waits for a stable grasp, then, for ``track_secs`` of
data time (and until an estimate of a later frame arrives, at most ``lag_secs`` more:
estimates trail their frames), compares each pose estimate with the world's truth of the same instant (the
estimate carries the stamp of the camera frames it came from, the GroundTruth of that
frame has the same stamp) while the scene pushes and twists the object in the hand.
The pose node tracks as it always does: warm-started from its last estimate, re-seeded
when the residual says a minimum is wrong (its ``recovered`` status).

Errors are those the pose benchmark uses: the angle between the estimated and true
object axes (``axis_deg``; the axis is a line for an object symmetric under a flip) and
the distance of the estimated origin from the true axis (``offaxis_mm``); a turn about
the axis of a body of revolution is not observable and not counted.

Jolts are found in the truth: a frame where the object moved more than ``jolt_mm`` or
turned more than ``jolt_deg`` since the frame before (a tap). The time to re-acquire a
jolt is from its frame to the first estimate after it within ``track_deg`` and
``track_mm``.

At the end it logs and publishes a ``summary`` event (JSON: estimates, median, p95 and
max of both errors, statuses, jolts and their re-acquire times), releases the object
and stops the graph. Its verdict (exit code 1) says the tracking failed: a p95 over
``max_p95_deg`` or ``max_p95_mm``, or a jolt never re-acquired.

Ports:
    inputs: ``grasp`` (GraspState), ``pose`` (PoseEstimate), ``truth`` (GroundTruth).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent, task ``antagonism``).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from msgspec import Meta

from messages import GraspState, GroundTruth, PoseEstimate
from messages.tasks import JoltRecord, Spread, TrackingSummary
from nodes.supervisor.base import SingleGraspTask, TaskParams
from perception.pose.symmetry import axis_error_deg, offaxis_error_m
from runtime.registry import register

TRUTH_KEPT = 600  # truths kept for matching (20 s at 30 fps): estimates trail by less


class AntagonismParams(TaskParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    track_secs: Annotated[float, Meta(gt=0)] = 6.0
    lag_secs: Annotated[float, Meta(gt=0)] = 10.0
    flip_symmetric: bool = True
    jolt_mm: Annotated[float, Meta(gt=0)] = 1.5
    jolt_deg: Annotated[float, Meta(gt=0)] = 4.0
    track_deg: Annotated[float, Meta(gt=0)] = 5.0
    track_mm: Annotated[float, Meta(gt=0)] = 2.0
    max_p95_deg: Annotated[float, Meta(gt=0)] = 5.0
    max_p95_mm: Annotated[float, Meta(gt=0)] = 3.0
    grasp_speed_m_per_s: float = 0.1


@dataclass
class Jolt:
    stamp_nanos: int
    moved_mm: float
    turned_deg: float
    reacquired_secs: float | None = None


def percentiles(values: list[float]) -> Spread:
    """Median, p95 and max (0 for no values), rounded for the summary."""
    if not values:
        return Spread(median=0.0, p95=0.0, max=0.0)
    arr = np.asarray(values)
    return Spread(
        median=round(float(np.median(arr)), 4),
        p95=round(float(np.percentile(arr, 95)), 4),
        max=round(float(arr.max()), 4),
    )


@register("supervisor.antagonism")
class AntagonismSupervisor(SingleGraspTask):
    """Reports how well the pose estimate follows the object (see the module docstring)."""

    Params = AntagonismParams
    inputs = {"grasp": GraspState, "pose": PoseEstimate, "truth": GroundTruth}
    task = "antagonism"

    def setup(self) -> None:
        super().setup()
        self.truths: OrderedDict[int, np.ndarray] = OrderedDict()
        self.last_truth: np.ndarray | None = None
        self.stable_nanos = 0
        self.axis_deg: list[float] = []
        self.offaxis_mm: list[float] = []
        self.statuses: dict[str, int] = {}
        self.waiting: dict[int, PoseEstimate] = {}  # estimates whose truth has not come
        self.end_stamp: int | None = None  # the first estimate's after the window
        self.jolts: list[Jolt] = []

    def on_stable(self) -> None:
        self.stable_nanos = self.now_nanos
        # No pose in these events: which estimate is the newest when a grasp state or a
        # truth arrives depends on the order of two topics, which a replay need not keep.
        self.event("tracking", f"for {self.params.track_secs:g} s", with_pose=False)

    def advance(self, elapsed_secs: float) -> None:
        super().advance(elapsed_secs)
        # Estimates trail the frames they come from: wait for one of the end's frame,
        # but no longer than lag_secs of data time.
        end = self.stable_nanos + self.params.track_secs * 1e9
        if self.state == "holding" and self.now_nanos > end + self.params.lag_secs * 1e9:
            self._summary()

    def on_truth(self, msg: GroundTruth) -> None:
        pose = np.asarray(msg.tool_from_object, dtype=np.float64)
        if self.state == "holding" and self.last_truth is not None:
            moved_mm = float(np.linalg.norm(pose[:3, 3] - self.last_truth[:3, 3])) * 1000
            cos = (np.trace(self.last_truth[:3, :3].T @ pose[:3, :3]) - 1) / 2
            turned_deg = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
            if moved_mm > self.params.jolt_mm or turned_deg > self.params.jolt_deg:
                self.jolts.append(Jolt(msg.header.stamp_nanos, moved_mm, turned_deg))
                detail = f"{moved_mm:.1f} mm, {turned_deg:.1f} deg in one frame"
                self.event("jolt", detail, with_pose=False)
        self.last_truth = pose
        stamp = msg.header.stamp_nanos
        self.truths[stamp] = pose
        while len(self.truths) > TRUTH_KEPT:
            self.truths.popitem(last=False)
        if stamp in self.waiting:
            self._compare(self.waiting.pop(stamp), pose)
        self._end_when_judged()

    def on_pose(self, msg: PoseEstimate) -> None:
        super().on_pose(msg)
        stamp = msg.header.stamp_nanos
        if self.state != "holding" or stamp < self.stable_nanos:
            return
        if stamp > self.stable_nanos + self.params.track_secs * 1e9:
            if self.end_stamp is None:
                self.end_stamp = stamp
            self._end_when_judged()
            return
        # An estimate and the truth of its frame come on two topics, in either order.
        truth = self.truths.get(stamp)
        if truth is None:
            self.waiting[stamp] = msg
        else:
            self._compare(msg, truth)

    def _end_when_judged(self) -> None:
        """Summarize once an estimate after the window came and the truths up to its
        frame did: every estimate of the window has then met its truth, if it has one."""
        if (
            self.state == "holding"
            and self.end_stamp is not None
            and self.truths
            and next(reversed(self.truths)) >= self.end_stamp
        ):
            self._summary()

    def _compare(self, msg: PoseEstimate, truth: np.ndarray) -> None:
        stamp = msg.header.stamp_nanos
        self.statuses[msg.status] = self.statuses.get(msg.status, 0) + 1
        est = np.asarray(msg.tool_from_object, dtype=np.float64)
        axis = axis_error_deg(est, truth, flip_symmetric=self.params.flip_symmetric)
        off = offaxis_error_m(est, truth) * 1000
        self.axis_deg.append(axis)
        self.offaxis_mm.append(off)
        on_track = axis <= self.params.track_deg and off <= self.params.track_mm
        for jolt in self.jolts:
            if jolt.reacquired_secs is None and stamp >= jolt.stamp_nanos and on_track:
                jolt.reacquired_secs = (stamp - jolt.stamp_nanos) / 1e9

    def _summary(self) -> None:
        p = self.params
        axis, off = percentiles(self.axis_deg), percentiles(self.offaxis_mm)
        lost = [j for j in self.jolts if j.reacquired_secs is None]
        ok = (
            bool(self.axis_deg)
            and axis.p95 <= p.max_p95_deg
            and off.p95 <= p.max_p95_mm
            and not lost
        )
        summary = TrackingSummary(
            estimates=len(self.axis_deg),
            unmatched=len(self.waiting),
            axis_deg=axis,
            offaxis_mm=off,
            statuses=dict(sorted(self.statuses.items())),
            jolts=[
                JoltRecord(
                    t_secs=round((j.stamp_nanos - self.stable_nanos) / 1e9, 3),
                    moved_mm=round(j.moved_mm, 2),
                    turned_deg=round(j.turned_deg, 2),
                    reacquire_secs=None
                    if j.reacquired_secs is None
                    else round(j.reacquired_secs, 3),
                )
                for j in self.jolts
            ],
            success=ok,
        )
        self.event("summary", data=summary, with_pose=False)
        self.release("tracking done")
        self.finish(
            f"{self.task}: {len(self.axis_deg)} estimates, axis p95 {axis.p95:.2f} deg,"
            f" off-axis p95 {off.p95:.2f} mm, {len(self.jolts)} jolt(s),"
            f" {len(lost)} not re-acquired: {'tracked' if ok else 'LOST'}",
            exit_code=0 if ok else 1,
        )

    def timeout_exit_code(self) -> int:
        return 1  # never tracked for track_secs
