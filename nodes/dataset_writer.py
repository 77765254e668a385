"""``dataset_writer``: records the frames of stable grasps into a tactile dataset.

Ports:
    inputs: ``left``, ``right`` (ToFImage): the bubbles' frames, paired by stamp;
        ``grasp`` (GraspState): frames count only while the grasp is stable, from the
        stamp it became stable; ``truth`` (GroundTruth, optional): the object's class
        and the sensor-noise seed at each stamp (the simulator's; on hardware the
        supervisor's ``grasp_start`` names the object instead, and there is no seed);
        ``event`` (TaskEvent from ``supervisor.autolabel``):
        ``run_start`` opens (or resumes) the dataset with its seeds and scene
        parameters, ``grasp_start`` / ``grasp_end`` bracket a grasp.
    outputs: ``progress`` (TaskEvent, task ``autolabel``): ``grasp_written`` (data: a
        ``GraspWritten``: ``grasp_id``, ``frames``, ``object_class``) or ``grasp_skipped``
        (a ``GraspSkipped``: no stable frame, or labels that disagree).

Everything is decided by stamps, not by arrival order: under load the cameras' frames
trail the grasp monitor and the supervisor's events by a good fraction of a second, so a
frame pair waits until the grasp state at its stamp is known, and a grasp is written once
a frame past its ``grasp_end`` stamp has arrived; several grasps may wait at once (the
frames can trail by more than a whole grasp). A clean stop writes what is still open.

The format is :mod:`perception.classify.dataset` (an ``.npz`` per grasp, a JSON
manifest); a grasp reaches the manifest only once its file is complete, so a stopped run
resumes where the manifest ends. Of the stable frames, every ``frame_stride``-th pair is
kept, at most ``max_frames_per_grasp`` (frames of one held grasp differ little). Each
grasp's manifest entry has the supervisor's grasp parameters and, from the simulator's
ground truth, ``sensor_noise_seed``: with the auto-labelling seed, all it takes to make
the same grasps with the same noise again.
"""

from __future__ import annotations

import bisect
from collections import Counter, OrderedDict, deque
from dataclasses import dataclass, field
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from messages.base import Header
from messages.errors import NodeError
from messages.tasks import (
    GraspRef,
    GraspSkipped,
    GraspStart,
    GraspWritten,
    RunStart,
    TaskData,
    TaskEventName,
)
from messages.types import GraspState, GroundTruth, TaskEvent, ToFImage
from perception.classify.autolabel import DEFAULT_OBJECTS
from perception.classify.dataset import DatasetError, DatasetWriter, GraspBuffer
from perception.contact import InstantPairs
from runtime.node import Node
from runtime.registry import register

TASK = "autolabel"


class DatasetWriterParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``dataset``: directory; ``classes``: label order; ``resume``: continue a dataset
    that exists (else it is an error); ``max_skew_secs``: largest stamp difference of a
    left/right pair; ``max_history``: most grasp states and ground truths kept while an
    open grasp's frames are awaited (frames that trail by more lose their state);
    ``max_unpaired``: most frames of one camera kept waiting for the other camera's."""

    dataset: Annotated[str, Meta(description="the dataset directory")] = "out/datasets/autolabel"
    classes: Annotated[tuple[str, ...], Meta(description="class names in label order")] = (
        DEFAULT_OBJECTS
    )
    resume: Annotated[
        bool, Meta(description="continue a dataset that exists (else it is an error)")
    ] = True
    frame_stride: Annotated[
        int,
        Meta(description="of a grasp's stable frames, every n-th left/right pair is kept", ge=1),
    ] = 3
    max_frames_per_grasp: Annotated[
        int,
        Meta(description="at most this many pairs of one grasp (its frames differ little)", ge=1),
    ] = 10
    max_skew_secs: Annotated[
        float, Meta(description="largest stamp difference of a left/right pair", ge=0)
    ] = 0.001
    max_history: Annotated[
        int,
        Meta(
            ge=1,
            description="most grasp states and ground truths kept while an open grasp's frames are awaited",
        ),
    ] = 100_000
    max_unpaired: Annotated[
        int, Meta(ge=1, description="most frames of one camera kept waiting for the other's")
    ] = 2000

    def __post_init__(self) -> None:
        if not self.dataset:
            raise ValueError("`dataset` must be a directory path, got ''")
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            raise ValueError(f"`classes` must be >= 2 distinct names, got {list(self.classes)}")


@dataclass
class _Grasp:
    """One grasp of the run, from its ``grasp_start`` to its ``grasp_end`` stamp."""

    grasp_id: int
    params: dict[str, Any]
    start_nanos: int
    end_nanos: int | None = None
    buffer: GraspBuffer = field(default_factory=GraspBuffer)
    labels: Counter[str] = field(default_factory=Counter)
    noise_seeds: set[int] = field(default_factory=set)
    pairs_seen: int = 0


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
        self.grasps: list[_Grasp] = []  # started, not yet written (in start order)
        # The grasp state over time: stamps (increasing) and whether stable from then on.
        self.state_stamps: list[int] = []
        self.state_stable: list[bool] = []
        # Each camera's frames not paired yet; ``lost``: those whose other half never came.
        self.halves: InstantPairs[ToFImage] = InstantPairs(self.params.max_unpaired)
        self.waiting: deque[tuple[ToFImage, ToFImage]] = deque()
        # The simulator's ground truth at recent stamps.
        self.truth: OrderedDict[int, GroundTruth] = OrderedDict()

    # -- run and grasp bracketing -------------------------------------------------------

    def on_event(self, msg: TaskEvent) -> None:
        if msg.task != TASK:
            return
        data = msg.data
        stamp = msg.header.stamp_nanos
        if isinstance(data, RunStart):
            try:
                self.writer = DatasetWriter(
                    self.params.dataset,
                    classes=self.params.classes,
                    seeds=data.seeds,
                    scene=data.scene,
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
        elif isinstance(data, GraspStart):
            for grasp in self.grasps:  # a grasp left open (a lost event) ends where this starts
                if grasp.end_nanos is None:
                    grasp.end_nanos = stamp
            self.grasps.append(_Grasp(data.grasp_id, data.params, stamp))
        elif isinstance(data, GraspRef):  # grasp_end, grasp_failed
            for grasp in self.grasps:
                if grasp.grasp_id == data.grasp_id:
                    grasp.end_nanos = stamp
            self._decide()

    def teardown(self) -> None:
        while self.grasps:
            self._finish(self.grasps[0])

    def _finish(self, grasp: _Grasp) -> None:
        self.grasps.remove(grasp)
        stamp = grasp.end_nanos or grasp.start_nanos
        if self.writer is None:
            raise NodeError(f"{self.name}: grasp {grasp.grasp_id} ended before any run_start")
        if len(grasp.buffer) == 0:
            # Not silent: a grasp the supervisor held and that keeps no frame is a loss
            # to look into (no stable frame pair arrived: frames lost upstream?).
            self.io.log.warning(
                "%s: grasp %d skipped: none of its frame pairs was stable "
                "(%d frames without their other half so far in this run)",
                self.name,
                grasp.grasp_id,
                self.halves.lost,
            )
            self._progress("grasp_skipped", GraspSkipped(grasp_id=grasp.grasp_id), stamp)
            return
        label = grasp.labels.most_common(1)[0][0]
        expected = grasp.params.get("class_label")
        if len(grasp.labels) > 1 or (expected and expected != label):
            # Labels must be beyond doubt: a grasp whose frames disagree is dropped.
            self.io.log.error(
                "%s: grasp %d dropped: labels %s, requested %r",
                self.name,
                grasp.grasp_id,
                dict(grasp.labels),
                expected,
            )
            skipped = GraspSkipped(grasp_id=grasp.grasp_id, labels=dict(grasp.labels))
            self._progress("grasp_skipped", skipped, stamp)
            return
        params = dict(grasp.params)
        if grasp.noise_seeds:  # one seed, unless the world was restarted with another
            seeds = sorted(grasp.noise_seeds)
            params["sensor_noise_seed"] = seeds[0] if len(seeds) == 1 else seeds
        try:
            self.writer.write_grasp(grasp.grasp_id, label, grasp.buffer, params)
        except DatasetError as err:
            raise NodeError(f"{self.name}: grasp {grasp.grasp_id}: {err}") from err
        written = GraspWritten(
            grasp_id=grasp.grasp_id, frames=len(grasp.buffer), object_class=label
        )
        self._progress("grasp_written", written, stamp)

    def _progress(self, event: TaskEventName, data: TaskData, stamp: int) -> None:
        self.io.publish(
            "progress",
            TaskEvent(header=Header(stamp_nanos=stamp), task=TASK, event=event, data=data),
        )

    # -- the grasp state, labels and frames, by stamp -------------------------------------

    def on_grasp(self, msg: GraspState) -> None:
        stamp = msg.header.stamp_nanos
        if self.state_stamps and stamp < self.state_stamps[-1]:
            return  # out of order: the timeline only moves forward
        self.state_stamps.append(stamp)
        self.state_stable.append(bool(msg.stable))
        self._decide()
        self._trim()

    def _trim(self) -> None:
        """Forgets the grasp states and ground truth no frame to come can need: those
        before the oldest open grasp's start (and before the oldest waiting pair), the
        last state before it kept. Frames may trail by many grasps, so this is no fixed
        window; ``max_history`` bounds it all the same (a camera that stopped), and is
        the window while no grasp is open."""
        cut = 0
        if self.grasps:  # between grasps, the next one may start before the newest state
            horizon = min(g.start_nanos for g in self.grasps)
            if self.waiting:
                horizon = min(horizon, max(p.header.stamp_nanos for p in self.waiting[0]))
            cut = max(bisect.bisect_right(self.state_stamps, horizon) - 1, 0)
        limit = self.params.max_history
        over = len(self.state_stamps) - cut - limit
        if over > 0:
            if self.grasps:
                self.io.log.warning(
                    "%s: frames of open grasps trail the grasp state by more than "
                    "max_history (%d) states; the oldest are forgotten",
                    self.name,
                    limit,
                )
            cut += over + limit // 4  # in batches: a list's head is costly to delete
        if cut:
            del self.state_stamps[:cut], self.state_stable[:cut]
        oldest = self.state_stamps[0] if self.state_stamps else 0
        while self.truth and (
            next(iter(self.truth)) < oldest or len(self.truth) > self.params.max_history
        ):
            self.truth.popitem(last=False)

    def _stable_at(self, stamp: int) -> bool | None:
        """Whether the grasp was stable at ``stamp``; None while that is not known yet."""
        if not self.state_stamps or self.state_stamps[-1] < stamp:
            return None
        index = bisect.bisect_right(self.state_stamps, stamp) - 1
        return index >= 0 and self.state_stable[index]

    def on_truth(self, msg: GroundTruth) -> None:
        self.truth[msg.header.stamp_nanos] = msg
        if len(self.truth) > self.params.max_history:
            self._trim()

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, port: str, msg: ToFImage) -> None:
        lost = self.halves.lost
        half = self.halves.match(port, msg.header.stamp_nanos, msg, self.params.max_skew_secs * 1e9)
        if self.halves.lost > lost and (lost == 0 or self.halves.lost // 100 > lost // 100):
            self.io.log.warning(
                "%s: %d frames without their other half so far", self.name, self.halves.lost
            )
        if half is None:
            return
        self.waiting.append((msg, half) if port == "left" else (half, msg))
        self._decide()

    def _decide(self) -> None:
        """Settle every waiting pair whose grasp state is known, in stamp order."""
        while self.waiting:
            left, right = self.waiting[0]
            stamp = max(left.header.stamp_nanos, right.header.stamp_nanos)
            stable = self._stable_at(stamp)
            if stable is None:
                return
            self.waiting.popleft()
            for grasp in list(self.grasps):
                if grasp.end_nanos is not None and stamp > grasp.end_nanos:
                    self._finish(grasp)  # the frames have caught up with the grasp's end
                elif grasp.start_nanos <= stamp and stable:
                    self._keep(grasp, left, right, stamp)

    def _keep(self, grasp: _Grasp, left: ToFImage, right: ToFImage, stamp: int) -> None:
        if len(grasp.buffer) >= self.params.max_frames_per_grasp:
            return
        grasp.pairs_seen += 1
        if (grasp.pairs_seen - 1) % self.params.frame_stride:
            return
        truth = self.truth.get(left.header.stamp_nanos) or self.truth.get(right.header.stamp_nanos)
        label = grasp.params.get("class_label") if truth is None else truth.object_class
        if label is None:
            self.io.log.warning("%s: no label for the frame at %d; skipped", self.name, stamp)
            return
        if left.depth_m.size == 0 or left.ir.size == 0:
            raise NodeError(f"{self.name}: frames need depth and IR (enable both sim effects)")
        grasp.labels[label] += 1
        if truth is not None:
            grasp.noise_seeds.add(truth.noise_seed)
        grasp.buffer.add(left.depth_m, right.depth_m, left.ir, right.ir, stamp)
