"""``supervisor.sort`` (paper, task 1, one object): classify the grasped object, route it.

Closes the gripper, waits for a stable grasp, averages ``vote_frames`` classifier
outputs, sends the object to its bin (``bins``: class -> bin), releases, ends. When the
averaged probability of the best class is under ``min_confidence``, the object goes to
``unsure_bin`` instead (a reject bin for a person or a regrasp): the classifier's
confidence separates its errors well (docs/classifier.md, "Acting on confidence").
``supervisor.dish_loading`` runs a whole sink of objects.

Ports:
    inputs: ``grasp`` (GraspState); ``classes`` (ClassProbabilities); ``pose``
        (PoseEstimate, optional: the last estimate is reported with each event).
    outputs: ``command`` (GripperCommand), ``event`` (TaskEvent, task ``sort``).
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from messages import ClassProbabilities, GraspState, PoseEstimate
from messages.tasks import SortChoice
from nodes.supervisor.base import SingleGraspTask, TaskParams
from runtime.registry import register

DEFAULT_BINS = (
    ("mug", "dishwasher"),
    ("wine_glass", "dishwasher"),
    ("pet_bottle", "recycling"),
    ("square_bottle", "recycling"),
)


class Vote:
    """The mean of a few classifier outputs (restarted when the class list changes)."""

    def __init__(self) -> None:
        self.votes: list[np.ndarray] = []
        self.classes: list[str] = []

    def add(self, msg: ClassProbabilities) -> int:
        """Add one output; returns how many are in the vote."""
        if self.classes and list(msg.classes) != self.classes:
            self.votes.clear()
        self.classes = list(msg.classes)
        self.votes.append(np.asarray(msg.probabilities, dtype=np.float64))
        return len(self.votes)

    def result(self) -> tuple[str, float]:
        """The best class of the mean and its mean probability."""
        mean = np.mean(self.votes, axis=0)
        return self.classes[int(np.argmax(mean))], float(mean.max())

    def clear(self) -> None:
        self.votes.clear()


class SortParams(TaskParams, frozen=True, kw_only=True, forbid_unknown_fields=True):
    vote_frames: Annotated[int, Meta(ge=1)] = 5
    bins: tuple[tuple[str, str], ...] = msgspec.field(default=DEFAULT_BINS)
    min_confidence: Annotated[
        float,
        Meta(
            description="below this the unsure bin is used (0: always route to the best class's bin)",
            ge=0.0,
            le=1.0,
        ),
    ] = 0.0
    unsure_bin: str = "manual"


@register("supervisor.sort")
class SortSupervisor(SingleGraspTask):
    """Classify the grasped object, route it to its bin, release it."""

    Params = SortParams
    inputs = {"grasp": GraspState, "classes": ClassProbabilities, "pose": PoseEstimate}
    optional_inputs = frozenset({"pose"})
    task = "sort"

    def setup(self) -> None:
        super().setup()
        self.vote = Vote()
        self.sorted: SortChoice | None = None

    def on_classes(self, msg: ClassProbabilities) -> None:
        if self.state != "holding":
            return
        if self.vote.add(msg) >= self.params.vote_frames:
            best, confidence = self.vote.result()
            if confidence < self.params.min_confidence:
                bin_name = self.params.unsure_bin
                self.event(
                    "unsure",
                    f"{best} ({confidence:.3f} < {self.params.min_confidence:g}) -> {bin_name}",
                )
            else:
                bin_name = dict(self.params.bins).get(best, "unknown")
                self.event("classified", f"{best} ({confidence:.3f}) -> {bin_name}")
            self.sorted = SortChoice(class_name=best, confidence=round(confidence, 4), bin=bin_name)
            self.release(f"{best} ({confidence:.3f}) placed in {bin_name}")

    def outcome(self) -> SortChoice | None:
        return self.sorted
