"""``dataset_writer``: records the frames of stable grasps into a tactile dataset.

Ports:
    inputs: ``left``, ``right`` (ToFImage): the bubbles' frames, paired by stamp;
        ``grasp`` (GraspState): frames count only while the grasp is stable, from the
        stamp it became stable; ``truth`` (GroundTruth, optional): the object's class
        at each stamp (the simulator's; on hardware the supervisor's ``grasp_start``
        names the object instead); ``event`` (TaskEvent from ``supervisor.autolabel``):
        ``run_start`` opens (or resumes) the dataset with its seeds and scene
        parameters, ``grasp_start`` / ``grasp_end`` bracket a grasp.
    outputs: ``progress`` (TaskEvent, task ``autolabel``): ``grasp_written`` (detail:
        JSON ``grasp_id``, ``frames``, ``object_class``) or ``grasp_skipped`` (no
        stable frame).

The format is :mod:`perception.classify.dataset` (an ``.npz`` per grasp, a JSON
manifest); a grasp reaches the manifest only once its file is complete, so a stopped run
resumes where the manifest ends. Of the stable frames, every ``frame_stride``-th pair is
kept, at most ``max_frames_per_grasp`` (frames of one held grasp differ little).
"""

from __future__ import annotations

import json
from collections import Counter, OrderedDict
from dataclasses import dataclass

from messages.base import Header
from messages.errors import NodeError
from messages.types import GraspState, GroundTruth, TaskEvent, ToFImage
from perception.classify.autolabel import DEFAULT_OBJECTS
from perception.classify.dataset import DatasetError, DatasetWriter, GraspBuffer
from runtime.node import Node
from runtime.registry import register

TASK = "autolabel"


@dataclass(frozen=True, kw_only=True)
class DatasetWriterParams:
    """``dataset``: directory; ``classes``: label order; ``resume``: continue a dataset
    that exists (else it is an error); ``max_skew_secs``: largest stamp difference of a
    left/right pair."""

    dataset: str = "out/datasets/autolabel"
    classes: tuple[str, ...] = DEFAULT_OBJECTS
    resume: bool = True
    frame_stride: int = 3
    max_frames_per_grasp: int = 10
    max_skew_secs: float = 0.001

    def __post_init__(self) -> None:
        if not self.dataset:
            raise ValueError("`dataset` must be a directory path, got ''")
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            raise ValueError(f"`classes` must be >= 2 distinct names, got {list(self.classes)}")
        if self.frame_stride < 1:
            raise ValueError(f"`frame_stride` must be >= 1, got {self.frame_stride!r}")
        if self.max_frames_per_grasp < 1:
            raise ValueError(
                f"`max_frames_per_grasp` must be >= 1, got {self.max_frames_per_grasp!r}"
            )
        if not self.max_skew_secs >= 0:
            raise ValueError(f"`max_skew_secs` must be >= 0, got {self.max_skew_secs!r}")


@register("dataset_writer")
class DatasetWriterNode(Node):
    """Keeps stable-grasp frames, labels them, writes grasps (see the module docstring)."""

    Params = DatasetWriterParams
    inputs = {
        "left": ToFImage,
        "right": ToFImage,
        "grasp": GraspState,
        "truth": GroundTruth,
        "event": TaskEvent,
    }
    optional_inputs = frozenset({"truth"})
    outputs = {"progress": TaskEvent}

    def setup(self) -> None:
        self.writer: DatasetWriter | None = None
        self.grasp_id: int | None = None
        self.grasp_params: dict = {}
        self.buffer = GraspBuffer()
        self.labels: Counter[str] = Counter()
        self.stable_since_nanos: int | None = None
        self.pending: dict[str, ToFImage] = {}
        self.pairs_seen = 0
        # The simulator's class at recent stamps (its messages may trail the images).
        self.truth: OrderedDict[int, str] = OrderedDict()

    # -- run and grasp bracketing -------------------------------------------------------

    def on_event(self, msg: TaskEvent) -> None:
        if msg.task != TASK:
            return
        detail = json.loads(msg.detail) if msg.detail else {}
        if msg.event == "run_start":
            try:
                self.writer = DatasetWriter(
                    self.params.dataset,
                    classes=self.params.classes,
                    seeds=detail.get("seeds", {}),
                    scene=detail.get("scene", {}),
                    resume=self.params.resume,
                )
            except DatasetError as err:
                raise NodeError(f"{self.name}: params.dataset: {err}") from err
            self.io.log.info(
                "%s: writing %s (%d grasps already there)",
                self.name,
                self.params.dataset,
                len(self.writer.done_grasp_ids()),
            )
        elif msg.event == "grasp_start":
            self.grasp_id = int(detail["grasp_id"])
            self.grasp_params = detail
            self.buffer = GraspBuffer()
            self.labels = Counter()
            self.pairs_seen = 0
        elif msg.event in ("grasp_end", "grasp_failed"):
            if self.grasp_id is not None and int(detail.get("grasp_id", -1)) == self.grasp_id:
                self._finish(msg.header.stamp_nanos)

    def _finish(self, stamp: int) -> None:
        grasp_id, self.grasp_id = self.grasp_id, None
        if self.writer is None:
            raise NodeError(f"{self.name}: grasp {grasp_id} ended before any run_start")
        if len(self.buffer) == 0:
            self._progress("grasp_skipped", {"grasp_id": grasp_id}, stamp)
            return
        label = self.labels.most_common(1)[0][0]
        expected = self.grasp_params.get("class_label")
        if len(self.labels) > 1 or (expected and expected != label):
            # Labels must be beyond doubt: a grasp whose frames disagree is dropped.
            self.io.log.error(
                "%s: grasp %d dropped: labels %s, requested %r",
                self.name,
                grasp_id,
                dict(self.labels),
                expected,
            )
            self._progress(
                "grasp_skipped", {"grasp_id": grasp_id, "labels": dict(self.labels)}, stamp
            )
            return
        try:
            self.writer.write_grasp(grasp_id, label, self.buffer, self.grasp_params)
        except DatasetError as err:
            raise NodeError(f"{self.name}: grasp {grasp_id}: {err}") from err
        self._progress(
            "grasp_written",
            {"grasp_id": grasp_id, "frames": len(self.buffer), "object_class": label},
            stamp,
        )

    def _progress(self, event: str, detail: dict, stamp: int) -> None:
        self.io.publish(
            "progress",
            TaskEvent(
                header=Header(stamp_nanos=stamp),
                task=TASK,
                event=event,
                detail=json.dumps(detail, sort_keys=True),
            ),
        )

    # -- frames ------------------------------------------------------------------------

    def on_grasp(self, msg: GraspState) -> None:
        if msg.stable and self.stable_since_nanos is None:
            self.stable_since_nanos = msg.header.stamp_nanos
        elif not msg.stable:
            self.stable_since_nanos = None
            self.pending.clear()

    def on_truth(self, msg: GroundTruth) -> None:
        self.truth[msg.header.stamp_nanos] = msg.object_class
        while len(self.truth) > 256:
            self.truth.popitem(last=False)

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, port: str, msg: ToFImage) -> None:
        stamp = msg.header.stamp_nanos
        if self.grasp_id is None or self.stable_since_nanos is None:
            return
        if stamp < self.stable_since_nanos or len(self.buffer) >= self.params.max_frames_per_grasp:
            return
        self.pending[port] = msg
        if len(self.pending) < 2:
            return
        left, right = self.pending["left"], self.pending["right"]
        if (
            abs(left.header.stamp_nanos - right.header.stamp_nanos)
            > self.params.max_skew_secs * 1e9
        ):
            return
        self.pending.clear()
        self.pairs_seen += 1
        if (self.pairs_seen - 1) % self.params.frame_stride:
            return
        label = self.truth.get(left.header.stamp_nanos) or self.truth.get(right.header.stamp_nanos)
        if label is None:
            label = self.grasp_params.get("class_label")
        if label is None:
            self.io.log.warning("%s: no label for the frame at %d; skipped", self.name, stamp)
            return
        if left.depth_m.size == 0 or left.ir.size == 0:
            raise NodeError(f"{self.name}: frames need depth and IR (enable both sim effects)")
        self.labels[label] += 1
        self.buffer.add(
            left.depth_m,
            right.depth_m,
            left.ir,
            right.ir,
            max(left.header.stamp_nanos, right.header.stamp_nanos),
        )
