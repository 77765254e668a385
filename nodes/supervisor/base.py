"""What every task supervisor shares: the data clock, events, gripper commands, time-outs.

Clock. A task keeps the time of its data: the stamp of the newest message it has
received. It starts ``start_delay_secs`` after its first message, times out
``timeout_secs`` after it, and stamps what it publishes with it, so the same messages
give the same decisions live and in a replay at any speed (lockstep replays of a task
are deterministic). A wall-clock watchdog times out a task that never hears anything.

Verdict. A task that ends by itself asks the graph to stop with its summary; a task
that failed (an object in a wrong bin, an object dropped) passes a non-zero
``exit_code``, which becomes the launcher's exit code.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from messages import GraspState, GripperCommand, Header, PoseEstimate, TaskEvent
from messages.base import Message
from messages.tasks import GraspSummary, SortChoice, TaskData, TaskEventName
from messages.types import GripperAction
from runtime.node import Node


class TaskParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What every task shares: how it grasps, releases and gives up."""

    grasp_on_start: Annotated[
        bool,
        Meta(description="send a grasp command once start_delay_secs have passed"),
    ] = True
    start_delay_secs: Annotated[
        float, Meta(description="data time from the first message received to the start", ge=0)
    ] = 0.3
    grasp_width_m: Annotated[float, Meta(description="the width_m of that grasp command", ge=0)] = (
        0.0
    )
    grasp_speed_m_per_s: Annotated[float, Meta(description="finger speed of the grasp", gt=0)] = (
        0.05
    )
    grasp_force_n: Annotated[float, Meta(description="grip force of the grasp", gt=0)] = 12.0
    release_width_m: Annotated[
        float, Meta(description="the opening a release command opens to", gt=0)
    ] = 0.11
    timeout_secs: Annotated[
        float,
        Meta(
            description="data time after the first message at which an unfinished task fails", gt=0
        ),
    ] = 30.0


class Task(Node):
    """The data clock, events, commands and time-outs of a task (module docstring)."""

    Params = TaskParams
    outputs = {"command": GripperCommand, "event": TaskEvent}
    task = "task"

    def setup(self) -> None:
        self.state = "idle"
        self.pose: PoseEstimate | None = None
        self.pose_statuses: dict[str, int] = {}
        self.first_nanos: int | None = None  # data time of the earliest message
        self.now_nanos = 0  # data time: the newest message's stamp
        self.msg_nanos = 0  # the stamp of the message being handled
        self.wall_started = self.io.now_nanos()
        self.io.add_timer(0.5, self._watchdog)

    @property
    def elapsed_secs(self) -> float:
        """Data time since the first message."""
        return 0.0 if self.first_nanos is None else (self.now_nanos - self.first_nanos) / 1e9

    def handle(self, port: str, msg: Message) -> None:
        """Advance the data clock to ``msg``'s stamp, then hand it to ``on_<port>``."""
        stamp = msg.header.stamp_nanos  # type: ignore[attr-defined]
        # The earliest stamp (0: none), not the first to arrive: live, which input's
        # message comes first is timing; a lockstep replay hands them over in stamp order.
        if self.first_nanos is None or (stamp and stamp < self.first_nanos):
            self.first_nanos = stamp
        self.now_nanos = max(self.now_nanos, stamp)
        self.msg_nanos = stamp
        self.advance(self.elapsed_secs)
        if self.state != "done" and self.elapsed_secs > self.params.timeout_secs:
            self.timeout()
        if self.state != "done":
            super().handle(port, msg)

    def advance(self, elapsed_secs: float) -> None:
        """Called with the data time before each message is handled."""

    def _watchdog(self) -> None:
        silent_secs = (self.io.now_nanos() - self.wall_started) / 1e9
        if self.first_nanos is None and silent_secs > self.params.timeout_secs:
            if self.state != "done":
                self.timeout("no input")

    def timeout(self, why: str = "") -> None:
        self.state = "done"
        detail = f"no completion within {self.params.timeout_secs:g} s"
        self.event("timeout", f"{detail} ({why})" if why else detail)
        self.finish(f"{self.task}: timeout", exit_code=self.timeout_exit_code())

    def timeout_exit_code(self) -> int:
        """The verdict of a run that timed out (0: a time-out is not a failure)."""
        return 0

    def finish(self, reason: str, *, exit_code: int = 0) -> None:
        """End the task and the graph with a one-line reason and the task's verdict."""
        self.state = "done"
        self.io.request_stop(reason, exit_code=exit_code)

    def command(
        self, command: GripperAction, width_m: float, *, force_n: float | None = None
    ) -> None:
        self.io.publish(
            "command",
            GripperCommand(
                header=Header(stamp_nanos=self.now_nanos or self.io.now_nanos()),
                command=command,
                width_m=float(width_m),
                speed_m_per_s=self.params.grasp_speed_m_per_s,
                force_n=float(self.params.grasp_force_n if force_n is None else force_n),
            ),
        )

    def event(
        self,
        event: TaskEventName,
        detail: str = "",
        *,
        data: TaskData | None = None,
        with_pose: bool = True,
        stamp_nanos: int | None = None,
    ) -> None:
        """Publish and log a TaskEvent; ``with_pose`` appends the last pose estimate to the
        detail. The log line shows ``data`` as JSON, then the detail. Stamped
        ``stamp_nanos``, by default the data time (the newest stamp handled)."""
        if with_pose and self.pose is not None and self.pose.status in ("ok", "recovered"):
            xyz_mm = self.pose.tool_from_object[:3, 3] * 1000
            detail += f" | pose xyz_mm=({xyz_mm[0]:.1f}, {xyz_mm[1]:.1f}, {xyz_mm[2]:.1f})"
        said = detail if data is None else f"{msgspec.json.encode(data).decode()}{detail}"
        self.io.log.info("%s: %s %s", self.task, event, said)
        self.io.publish(
            "event",
            TaskEvent(
                header=Header(stamp_nanos=stamp_nanos or self.now_nanos or self.io.now_nanos()),
                task=self.task,
                event=event,
                detail=detail,
                data=data,
            ),
        )

    def on_pose(self, msg: PoseEstimate) -> None:
        self.pose = msg
        self.pose_statuses[msg.status] = self.pose_statuses.get(msg.status, 0) + 1


class SingleGraspTask(Task):
    """Grasp on start, stop at release or timeout; subclasses decide when to release.

    At the end (the grasp released) it publishes a ``summary`` event (a
    :class:`messages.tasks.GraspSummary`: seconds held, the pose estimates by status, why
    it released, and where :meth:`outcome` says the object went) and
    stops the graph with the same in one line.
    """

    def setup(self) -> None:
        super().setup()
        self.grasp_stable_nanos: int | None = None
        self.release_sent_nanos: int | None = None
        self.release_detail = ""

    def advance(self, elapsed_secs: float) -> None:
        if self.state == "idle" and elapsed_secs >= self.params.start_delay_secs:
            if self.params.grasp_on_start:
                self.command("grasp", self.params.grasp_width_m)
            self.state = "grasping"
            self.event("grasping", "waiting for a stable grasp")

    def release(self, detail: str) -> None:
        self.command("release", self.params.release_width_m)
        self.state = "releasing"
        # The time held runs between the stamps of the messages that decided (the stable
        # grasp, the pull's frame), not the newest stamp seen at each: live, which other
        # input's message came first is timing, and a lockstep replay orders by stamp.
        self.release_sent_nanos = max(self.msg_nanos, self.grasp_stable_nanos or 0)
        self.release_detail = detail
        # Stamped so too: an input that need not wait for the deciding one (the
        # handover's grasp and shear, live, beside its wrench) may be ahead of it.
        self.event("release", detail, stamp_nanos=self.release_sent_nanos)

    def on_grasp(self, msg: GraspState) -> None:
        if msg.event == "stable" and self.state == "grasping":
            self.state = "holding"
            self.grasp_stable_nanos = msg.header.stamp_nanos
            self.event(
                "stable",
                f"pressure rise {msg.pressure_rise_left_pa:.0f}/{msg.pressure_rise_right_pa:.0f} Pa",
            )
            self.on_stable()
        elif msg.event == "released" and self.state in ("holding", "releasing"):
            self.event("done", "grasp released")
            self.on_released()

    def on_released(self) -> None:
        """The grasp let go after a release: the task is over, with its summary."""
        held = None
        if self.grasp_stable_nanos is not None and self.release_sent_nanos is not None:
            held = round((self.release_sent_nanos - self.grasp_stable_nanos) / 1e9, 3)
        ok = sum(self.pose_statuses.get(s, 0) for s in ("ok", "recovered"))
        estimates = sum(self.pose_statuses.values())
        summary = GraspSummary(
            held_secs=held,
            pose_statuses=dict(sorted(self.pose_statuses.items())),
            release=self.release_detail,
            sorted=self.outcome(),
        )
        self.event("summary", data=summary, with_pose=False)
        parts = [f"held {held:.2f} s" if held is not None else "never held"]
        if estimates:
            parts.append(f"pose ok in {ok} of {estimates} estimates")
        parts.append(f"released: {self.release_detail or '-'}")
        self.finish(f"{self.task}: done: {', '.join(parts)}")

    def outcome(self) -> SortChoice | None:
        """Where the task put the object, for its summary (none here)."""
        return None

    def on_stable(self) -> None:
        """Called once when the grasp becomes stable."""
