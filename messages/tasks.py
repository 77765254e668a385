"""What a task event says, typed: the event names and each event's record.

A :class:`messages.types.TaskEvent` names its event (:data:`TaskEventName`), says it in a
line for people (``detail``) and, where the event carries figures, holds them in
``data``: one of the records below, told apart on the wire by their ``kind`` field (a
msgspec tagged union), so a reader gets typed fields instead of parsing text. Units are
in the field names, as everywhere (``gap_mm``, ``held_secs``).

Bags recorded before ``data`` existed keep their figures as JSON text in ``detail``; they
still decode (``data`` is then ``None``; docs/bags.md, "Schema evolution").
"""

from __future__ import annotations

from typing import Any, Literal

import msgspec

TaskEventName = Literal[
    # every task supervisor (nodes/supervisor)
    "start",
    "grasping",
    "stable",
    "release",
    "done",
    "timeout",
    "summary",
    # sort, handover, antagonism, dish loading
    "classified",
    "unsure",
    "squeeze",
    "tracking",
    "jolt",
    "regrasp",
    "place",
    "object",
    # the autolabel run and the dataset writer's answers (nodes/autolabel.py,
    # nodes/dataset_writer.py)
    "run_start",
    "run_end",
    "grasp_start",
    "grasp_end",
    "grasp_failed",
    "grasp_written",
    "grasp_skipped",
]
"""``TaskEvent.event``: what happened."""


class TaskRecord(msgspec.Struct, kw_only=True, tag_field="kind"):
    """Base of the records a task event carries (``kind`` names which one)."""


class SortChoice(msgspec.Struct, kw_only=True):
    """Where the sort task put the object, and why."""

    class_name: str
    confidence: float
    bin: str


class GraspSummary(TaskRecord, tag="grasp_summary"):
    """A single-grasp task's ``summary`` (sort, handover): time held from the stable grasp
    to the release, the pose estimates by status, why it released, and the sort's choice."""

    held_secs: float | None
    pose_statuses: dict[str, int]
    release: str
    sorted: SortChoice | None = None


class PlacementSummary(TaskRecord, tag="placement_summary"):
    """The stacking task's ``summary``: when it released, and what the simulator saw of
    the placement (all ``None`` and ``outcome`` ``unknown`` without a placement truth)."""

    release_secs: float
    outcome: Literal["placed", "dropped", "unknown"]
    t_secs: float | None = None
    touch_secs: float | None = None
    gap_mm: float | None = None
    push_mm: float | None = None
    tilt_deg: float | None = None


class Spread(msgspec.Struct, kw_only=True):
    """Median, 95th percentile and maximum of a series (0 for none)."""

    median: float
    p95: float
    max: float


class JoltRecord(msgspec.Struct, kw_only=True):
    """One jolt of the held object: when (from the stable grasp), how far, and how long
    until the pose tracked it again (``None``: never)."""

    t_secs: float
    moved_mm: float
    turned_deg: float
    reacquire_secs: float | None


class TrackingSummary(TaskRecord, tag="tracking_summary"):
    """The antagonism task's ``summary``: pose error against the truth while held."""

    estimates: int
    unmatched: int
    axis_deg: Spread
    offaxis_mm: Spread
    statuses: dict[str, int]
    jolts: list[JoltRecord]
    success: bool


class ObjectOutcome(TaskRecord, tag="object_outcome"):
    """What happened to one object of the dish-loading task (``object``)."""

    index: int
    object: str  # what the task asked the world for (the scene's order)
    true_class: str = "?"  # from GroundTruth while held ("?" without it)
    predicted: str = ""
    probability: float = 0.0
    regrasps: int = 0
    destination: str = ""
    right: bool | None = None  # None: unknown (no truth) or not judged (manual bin)


class LoadingSummary(TaskRecord, tag="loading_summary"):
    """The dish-loading task's ``summary``: objects routed right, wrong, to the manual bin."""

    objects: int
    right: int
    wrong: int
    manual: int
    regrasps: int
    task_secs: float
    objects_per_minute: float


class RunStart(TaskRecord, tag="run_start"):
    """An autolabel run begins: its seeds and the scene generator's settings, as the
    dataset's manifest records them."""

    seeds: dict[str, int]
    scene: dict[str, Any]


class RunEnd(TaskRecord, tag="run_end"):
    """An autolabel run ends: grasps held to the end, and those that never became stable."""

    finished: int
    failed: int


class GraspStart(TaskRecord, tag="grasp_start"):
    """An autolabel grasp begins; ``params`` is the sample's record for the manifest."""

    grasp_id: int
    params: dict[str, Any]


class GraspRef(TaskRecord, tag="grasp"):
    """Which grasp an event is about (``grasp_end``, ``grasp_failed``)."""

    grasp_id: int


class GraspWritten(TaskRecord, tag="grasp_written"):
    """The dataset writer kept a grasp: its frames and the class they were labelled."""

    grasp_id: int
    frames: int
    object_class: str


class GraspSkipped(TaskRecord, tag="grasp_skipped"):
    """The dataset writer kept nothing of a grasp (no stable frame, or labels that disagree)."""

    grasp_id: int
    labels: dict[str, int] = msgspec.field(default_factory=dict)


TaskData = (
    GraspSummary
    | PlacementSummary
    | TrackingSummary
    | ObjectOutcome
    | LoadingSummary
    | RunStart
    | RunEnd
    | GraspStart
    | GraspRef
    | GraspWritten
    | GraspSkipped
)
"""``TaskEvent.data``: one of the records above."""
