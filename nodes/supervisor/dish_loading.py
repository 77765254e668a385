"""``supervisor.dish_loading`` (paper, task 1: dish loading with recycling separation).

A sink holds ``objects`` objects (the classes in shuffled blocks of one of each, so six
objects hold all four classes), each lying at a random pose after a drop
(``perception.classify.autolabel.GraspGenerator``, seeded by ``seed``). For each:

    approach (``place``: the world puts the object between the open jaws) -> settle ->
    close -> wait for the grasp monitor's stable grasp -> average ``vote_frames``
    classifier outputs -> dishes (mug, wine glass) to the rack, recycling (PET and
    square bottles) to the bin (``bins``) -> release -> the next object.

An object whose averaged best-class probability is under ``min_confidence`` (or that
gives no vote within ``vote_timeout_secs``, or no stable grasp within
``stable_timeout_secs``) is put down and grasped again at another height (a new draw of
the same object whose grasp point lies at least ``min_height_change_m`` from the
last), at most ``max_regrasps`` times; then it goes to ``unsure_bin``.

``bins`` (class -> bin) is where the task puts what it predicts; ``truth_bins`` is
where each class belongs, the judge's table (empty: the same as ``bins``).

At the end the task logs one line per object (true class from the world's
GroundTruth, predicted class and probability, regrasps, destination, right or wrong),
publishes a ``summary`` event (JSON) and stops the graph; its verdict (the launcher's
exit code) is 1 when an object went to a wrong bin. The manual bin is not wrong: a
person sorts what lands there.

Ports:
    inputs: ``grasp`` (GraspState; its stamps pace the task), ``classes``
        (ClassProbabilities), ``truth`` (GroundTruth, optional: without it, as on
        hardware, right or wrong is unknown).
    outputs: ``place`` (messages.classify.GraspRequest) to the world (the arm on
        hardware), ``command`` (GripperCommand), ``event`` (TaskEvent, task
        ``dish_loading``): ``object`` (JSON per object), ``summary`` (JSON).
"""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from messages import ClassProbabilities, GraspState, GroundTruth, Header
from messages.classify import GraspRequest
from messages.tasks import LoadingSummary, ObjectOutcome
from nodes.supervisor.base import Task, TaskParams
from nodes.supervisor.sort import DEFAULT_BINS, Vote
from perception.classify.autolabel import (
    DEFAULT_OBJECTS,
    GraspGenerator,
    GraspGeneratorParams,
    GraspSample,
)
from runtime.params import build_params
from runtime.registry import register

REGRASP_STRIDE = 100_000  # grasp ids of regrasps: the object's index + j * stride, j >= 1


class DishLoadingParams(TaskParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    seed: int = 0
    objects: Annotated[int, Meta(ge=1)] = 6
    classes: tuple[str, ...] = DEFAULT_OBJECTS
    bins: tuple[tuple[str, str], ...] = msgspec.field(default=DEFAULT_BINS)
    truth_bins: tuple[tuple[str, str], ...] = ()
    vote_frames: Annotated[int, Meta(ge=1)] = 3
    min_confidence: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.9
    max_regrasps: Annotated[int, Meta(ge=0)] = 2
    unsure_bin: str = "manual"
    min_height_change_m: Annotated[float, Meta(ge=0)] = 0.015
    settle_secs: Annotated[float, Meta(ge=0)] = 0.2
    stable_timeout_secs: Annotated[float, Meta(gt=0)] = 3.0
    vote_timeout_secs: Annotated[float, Meta(gt=0)] = 5.0
    release_secs: Annotated[float, Meta(ge=0)] = 0.3
    grasp_speed_m_per_s: float = 0.1
    timeout_secs: float = 180.0

    def __post_init__(self) -> None:
        for name in ("bins", "truth_bins"):
            table = getattr(self, name)
            missing = sorted(set(self.classes) - {c for c, _ in table})
            if missing and table:
                raise ValueError(f"`{name}` has no bin for {missing}")
        self.generator_params()  # checks the class names

    def generator_params(self, classes: tuple[str, ...] | None = None) -> GraspGeneratorParams:
        """The generator's parameters, checked against its declaration."""
        given = {"objects": classes or self.classes, "seed": self.seed}
        params: GraspGeneratorParams = build_params(GraspGeneratorParams, given)
        return params


@register("supervisor.dish_loading")
class DishLoadingSupervisor(Task):
    """Clears a sink of objects into the rack, the recycling bin or the manual bin."""

    Params = DishLoadingParams
    inputs = {"grasp": GraspState, "classes": ClassProbabilities, "truth": GroundTruth}
    optional_inputs = frozenset({"truth"})
    outputs = {**Task.outputs, "place": GraspRequest}
    task = "dish_loading"

    def setup(self) -> None:
        super().setup()
        self.generator = GraspGenerator(self.params.generator_params())
        self.results: list[ObjectOutcome] = []
        self.sample: GraspSample | None = None
        self.phase_start: int | None = None
        self.stable_at = 0
        self.vote = Vote()
        # The world shows nothing until the first object is placed: a wall-clock timer
        # starts the run, or the first message does (a replay, where it comes first).
        self.io.add_timer(self.params.start_delay_secs or 0.01, self._start)

    # -- the run ----------------------------------------------------------------------

    def advance(self, elapsed_secs: float) -> None:
        self._start()

    def _start(self) -> None:
        if self.state == "idle":
            self.event("start", f"{self.params.objects} objects, seed {self.params.seed}")
            self._next_object()

    def _enter(self, state: str) -> None:
        self.state = state
        # Before the first message there is no data time: the phase starts with it.
        self.phase_start = self.now_nanos if self.first_nanos is not None else None

    def _phase_secs(self) -> float:
        if self.phase_start is None:
            self.phase_start = self.now_nanos
        return (self.now_nanos - self.phase_start) / 1e9

    def _next_object(self) -> None:
        index = len(self.results)
        if index >= self.params.objects:
            self._summary()
            return
        sample = self.generator.sample(index)
        self.results.append(ObjectOutcome(index=index, object=sample.object_name))
        self._place(sample)

    def _regrasp_sample(self, result: ObjectOutcome) -> GraspSample:
        """Another grasp of the same object, its grasp point away from the last one."""
        assert self.sample is not None
        gen = GraspGenerator(self.params.generator_params((result.object,)))
        first = 1 + 20 * result.regrasps
        candidates = [
            gen.sample(result.index + REGRASP_STRIDE * j) for j in range(first, first + 20)
        ]
        far = [
            s
            for s in candidates
            if abs(s.height_m - self.sample.height_m) >= self.params.min_height_change_m
        ]
        return (far or candidates)[0]

    def _place(self, sample: GraspSample) -> None:
        self.sample = sample
        self.io.publish(
            "place",
            GraspRequest(
                header=Header(stamp_nanos=self.now_nanos, frame_id="tool"),
                grasp_id=sample.grasp_id,
                object_name=sample.object_name,
                class_label=sample.class_label,
                tool_from_object=sample.tool_from_object,
                open_width_m=self.params.release_width_m,
                grasp_width_m=sample.grasp_width_m,
                force_n=sample.force_n,
            ),
        )
        self.vote.clear()
        self._enter("settle")

    def on_grasp(self, msg: GraspState) -> None:
        p = self.params
        if self.state == "settle" and self._phase_secs() >= p.settle_secs and not msg.stable:
            assert self.sample is not None
            self.command("grasp", self.sample.grasp_width_m, force_n=self.sample.force_n)
            self._enter("closing")
        elif self.state == "closing":
            if msg.stable:
                self.stable_at = msg.header.stamp_nanos
                self._enter("holding")
            elif self._phase_secs() > p.stable_timeout_secs:
                self._unsure("no stable grasp")
        elif self.state == "holding":
            if not msg.stable:
                self._unsure("the grasp was lost")
            elif self._phase_secs() > p.vote_timeout_secs:
                self._unsure("no classification")
        elif self.state == "releasing" and self._phase_secs() >= p.release_secs:
            if not msg.stable:
                if self.results[-1].destination:
                    self._object_done()
                    self._next_object()
                else:
                    self._regrasp()

    def on_truth(self, msg: GroundTruth) -> None:
        if self.state == "holding" and self.results:
            self.results[-1].true_class = msg.object_class

    def on_classes(self, msg: ClassProbabilities) -> None:
        if self.state != "holding" or msg.header.stamp_nanos < self.stable_at:
            return
        if self.vote.add(msg) < self.params.vote_frames:
            return
        result = self.results[-1]
        result.predicted, result.probability = self.vote.result()
        if result.probability >= self.params.min_confidence:
            self._route(dict(self.params.bins).get(result.predicted, self.params.unsure_bin))
        else:
            self._unsure(f"{result.predicted} at {result.probability:.3f}")

    def _unsure(self, why: str) -> None:
        result = self.results[-1]
        if result.regrasps < self.params.max_regrasps:
            self.event("regrasp", f"object {result.index} ({why}): put down, grasp again")
            self._release()
        else:
            self.event("unsure", f"object {result.index} ({why}) after {result.regrasps} regrasps")
            self._route(self.params.unsure_bin)

    def _route(self, bin_name: str) -> None:
        result = self.results[-1]
        result.destination = bin_name
        if bin_name != self.params.unsure_bin and result.true_class != "?":
            judge = dict(self.params.truth_bins or self.params.bins)
            result.right = judge.get(result.true_class) == bin_name
        self.event("place", f"object {result.index}: {result.predicted or '?'} -> {bin_name}")
        self._release()

    def _release(self) -> None:
        self.command("release", self.params.release_width_m, force_n=0.0)
        self._enter("releasing")

    def _regrasp(self) -> None:
        result = self.results[-1]
        sample = self._regrasp_sample(result)
        result.regrasps += 1
        self._place(sample)

    def _object_done(self) -> None:
        self.event("object", data=msgspec.structs.replace(self.results[-1]))

    # -- the end ------------------------------------------------------------------------

    def _summary(self) -> None:
        wrong = [r for r in self.results if r.right is False]
        right = sum(r.right is True for r in self.results)
        manual = sum(r.destination == self.params.unsure_bin for r in self.results)
        lines = [f"{'#':>2} {'true':14} {'predicted':14} {'p':>6} {'regrasps':>8} {'bin':11} ok"]
        for r in self.results:
            verdict = {True: "right", False: "WRONG", None: "-"}[r.right]
            lines.append(
                f"{r.index:2d} {r.true_class:14} {r.predicted or '?':14} {r.probability:6.3f}"
                f" {r.regrasps:8d} {r.destination:11} {verdict}"
            )
        for line in lines:
            self.io.log.info("%s: %s", self.task, line)
        minutes = max(self.elapsed_secs, 1e-9) / 60
        summary = LoadingSummary(
            objects=len(self.results),
            right=right,
            wrong=len(wrong),
            manual=manual,
            regrasps=sum(r.regrasps for r in self.results),
            task_secs=round(self.elapsed_secs, 3),
            objects_per_minute=round(len(self.results) / minutes, 3),
        )
        self.event("summary", data=summary)
        self.finish(
            f"{self.task}: {len(self.results)} objects, {right} right, {len(wrong)} wrong,"
            f" {manual} to the manual bin",
            exit_code=1 if wrong else 0,
        )

    def timeout_exit_code(self) -> int:
        return 1  # the sink was not cleared
