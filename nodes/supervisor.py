"""Task supervisors: the paper's manipulation tasks as small state machines.

``supervisor.handover`` (paper, task 3: shear-based release and handover)
    Closes the gripper on the object, waits for the grasp monitor's stable grasp, then
    watches both bubbles' shear; when the shear magnitude (the mean displacement per
    pixel of the membrane against the stable-grasp reference, ``ShearEstimate.magnitude_px``)
    stays above ``release_shear_px`` for ``confirm_frames`` frames (someone pulls), it
    opens the gripper and reports the pull direction. It ends the graph once the grasp
    is released, or at ``timeout_secs``.
``supervisor.sort`` (paper, task 1: dish loading with recycling separation)
    Closes the gripper, waits for a stable grasp, averages ``vote_frames`` classifier
    outputs, sends the object to its bin (``bins``: class -> bin), releases, ends. When
    the averaged probability of the best class is under ``min_confidence``, the object
    goes to ``unsure_bin`` instead (a reject bin for a person or a regrasp): the
    classifier's confidence separates its errors well (docs/classifier.md, "Acting on
    confidence").

Ports:
    inputs: ``grasp`` (GraspState); ``shear`` (ShearEstimate, handover);
        ``classes`` (ClassProbabilities, sort); ``pose`` (PoseEstimate, optional: the
        last estimate is reported with each event).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent).

Clock. A task keeps the time of its data: the stamp of the newest message it has
received. It grasps ``start_delay_secs`` after its first message, times out
``timeout_secs`` after it, and stamps what it publishes with it, so the same messages
give the same decisions live and in a replay at any speed (lockstep replays of a task
are deterministic). A wall-clock watchdog times out a task that never hears anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from messages import (
    ClassProbabilities,
    GraspState,
    GripperCommand,
    Header,
    PoseEstimate,
    ShearEstimate,
    TaskEvent,
)
from messages.base import Message
from runtime.node import Node
from runtime.registry import register

DEFAULT_BINS = (
    ("mug", "dishwasher"),
    ("wine_glass", "dishwasher"),
    ("pet_bottle", "recycling"),
    ("square_bottle", "recycling"),
)


@dataclass(frozen=True, kw_only=True)
class TaskParams:
    """What every task shares: how it grasps, releases and gives up."""

    grasp_on_start: bool = True
    start_delay_secs: float = 0.3
    grasp_width_m: float = 0.0
    grasp_speed_m_per_s: float = 0.05
    grasp_force_n: float = 12.0
    release_width_m: float = 0.11
    timeout_secs: float = 30.0

    def __post_init__(self) -> None:
        for name in ("grasp_speed_m_per_s", "grasp_force_n", "release_width_m", "timeout_secs"):
            if not getattr(self, name) > 0:
                raise ValueError(f"`{name}` must be > 0, got {getattr(self, name)!r}")
        if self.start_delay_secs < 0 or self.grasp_width_m < 0:
            raise ValueError("`start_delay_secs` and `grasp_width_m` must be >= 0")


class _Task(Node):
    """Grasp on start, stop at release or timeout; subclasses decide when to release."""

    Params = TaskParams
    outputs = {"command": GripperCommand, "event": TaskEvent}
    task = "task"

    def setup(self) -> None:
        self.state = "idle"
        self.pose: PoseEstimate | None = None
        self.first_nanos: int | None = None  # data time of the first message
        self.now_nanos = 0  # data time: the newest message's stamp
        self.wall_started = self.io.now_nanos()
        self.io.add_timer(0.5, self._watchdog)

    def handle(self, port: str, msg: Message) -> None:
        """Advance the data clock to ``msg``'s stamp, then hand it to ``on_<port>``."""
        stamp = msg.header.stamp_nanos  # type: ignore[attr-defined]
        if self.first_nanos is None:
            self.first_nanos = stamp
        self.now_nanos = max(self.now_nanos, stamp)
        self._advance((self.now_nanos - self.first_nanos) / 1e9)
        super().handle(port, msg)

    def _advance(self, elapsed_secs: float) -> None:
        if self.state == "idle" and elapsed_secs >= self.params.start_delay_secs:
            if self.params.grasp_on_start:
                self.command("grasp", self.params.grasp_width_m)
            self.state = "grasping"
            self.event("grasping", "waiting for a stable grasp")
        if self.state != "done" and elapsed_secs > self.params.timeout_secs:
            self.timeout()

    def _watchdog(self) -> None:
        silent_secs = (self.io.now_nanos() - self.wall_started) / 1e9
        if self.first_nanos is None and silent_secs > self.params.timeout_secs:
            if self.state != "done":
                self.timeout("no input")

    def timeout(self, why: str = "") -> None:
        self.state = "done"
        detail = f"no completion within {self.params.timeout_secs:g} s"
        self.event("timeout", f"{detail} ({why})" if why else detail)
        self.io.request_stop(f"{self.task}: timeout")

    def command(self, command: str, width_m: float) -> None:
        self.io.publish(
            "command",
            GripperCommand(
                header=Header(stamp_nanos=self.now_nanos or self.io.now_nanos()),
                command=command,
                width_m=width_m,
                speed_m_per_s=self.params.grasp_speed_m_per_s,
                force_n=self.params.grasp_force_n,
            ),
        )

    def event(self, event: str, detail: str = "") -> None:
        if self.pose is not None and self.pose.status in ("ok", "recovered"):
            xyz_mm = self.pose.tool_from_object[:3, 3] * 1000
            detail += f" | pose xyz_mm=({xyz_mm[0]:.1f}, {xyz_mm[1]:.1f}, {xyz_mm[2]:.1f})"
        self.io.log.info("%s: %s %s", self.task, event, detail)
        self.io.publish(
            "event",
            TaskEvent(
                header=Header(stamp_nanos=self.now_nanos or self.io.now_nanos()),
                task=self.task,
                event=event,
                detail=detail,
            ),
        )

    def release(self, detail: str) -> None:
        self.command("release", self.params.release_width_m)
        self.state = "releasing"
        self.event("release", detail)

    def on_grasp(self, msg: GraspState) -> None:
        if msg.event == "stable" and self.state == "grasping":
            self.state = "holding"
            self.event(
                "stable",
                f"pressure rise {msg.pressure_rise_left_pa:.0f}/{msg.pressure_rise_right_pa:.0f} Pa",
            )
            self.on_stable()
        elif msg.event == "released" and self.state in ("holding", "releasing"):
            self.state = "done"
            self.event("done", "grasp released")
            self.io.request_stop(f"{self.task}: done")

    def on_pose(self, msg: PoseEstimate) -> None:
        self.pose = msg

    def on_stable(self) -> None:
        """Called once when the grasp becomes stable."""


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


@register("supervisor.handover")
class HandoverSupervisor(_Task):
    """Release the object when a pull shears the bubbles (see the module docstring)."""

    Params = HandoverParams
    inputs = {"grasp": GraspState, "shear": ShearEstimate, "pose": PoseEstimate}
    optional_inputs = frozenset({"pose"})
    task = "handover"

    def setup(self) -> None:
        super().setup()
        self.above = {"left": 0, "right": 0}

    def on_shear(self, msg: ShearEstimate) -> None:
        if self.state != "holding" or not msg.has_reference:
            return
        pulled = msg.direction_defined and msg.magnitude_px >= self.params.release_shear_px
        self.above[msg.sensor] = self.above.get(msg.sensor, 0) + 1 if pulled else 0
        if self.above[msg.sensor] >= self.params.confirm_frames:
            angle = float(np.degrees(np.arctan2(msg.direction[1], msg.direction[0])))
            self.release(
                f"pull on the {msg.sensor} bubble: {msg.magnitude_px:.2f} px at {angle:.0f} deg "
                f"({np.linalg.norm(msg.shear_m) * 1000.0:.2f} mm)"
            )


@dataclass(frozen=True, kw_only=True)
class SortParams(TaskParams):
    vote_frames: int = 5
    bins: tuple[tuple[str, str], ...] = field(default=DEFAULT_BINS)
    min_confidence: float = 0.0  # 0: always route to the best class's bin
    unsure_bin: str = "manual"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.vote_frames < 1:
            raise ValueError(f"`vote_frames` must be >= 1, got {self.vote_frames!r}")
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f"`min_confidence` must be in [0, 1], got {self.min_confidence!r}")


@register("supervisor.sort")
class SortSupervisor(_Task):
    """Classify the grasped object, route it to its bin, release it."""

    Params = SortParams
    inputs = {"grasp": GraspState, "classes": ClassProbabilities, "pose": PoseEstimate}
    optional_inputs = frozenset({"pose"})
    task = "sort"

    def setup(self) -> None:
        super().setup()
        self.votes: list[np.ndarray] = []
        self.classes: list[str] = []

    def on_classes(self, msg: ClassProbabilities) -> None:
        if self.state != "holding":
            return
        if self.classes and list(msg.classes) != self.classes:
            self.votes.clear()
        self.classes = list(msg.classes)
        self.votes.append(np.asarray(msg.probabilities, dtype=np.float64))
        if len(self.votes) >= self.params.vote_frames:
            mean = np.mean(self.votes, axis=0)
            best = self.classes[int(np.argmax(mean))]
            confidence = float(mean.max())
            if confidence < self.params.min_confidence:
                bin_name = self.params.unsure_bin
                self.event(
                    "unsure",
                    f"{best} ({confidence:.3f} < {self.params.min_confidence:g}) -> {bin_name}",
                )
            else:
                bin_name = dict(self.params.bins).get(best, "unknown")
                self.event("classified", f"{best} ({confidence:.3f}) -> {bin_name}")
            self.release(f"placed in {bin_name}")
