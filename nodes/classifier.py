"""``classifier.resnet18``: tactile object classification of stable grasps.

Ports:
    inputs: ``left`` (ToFImage), ``right`` (ToFImage), ``grasp`` (GraspState).
    outputs: ``probabilities`` (ClassProbabilities): one per left/right frame pair
        whose two stamps are within ``max_skew_secs`` of each other and not older than
        the moment the grasp became stable; nothing while the grasp is not stable.

The network, preprocessing and checkpoint format are :mod:`perception.classify`. At
setup the node loads ``model`` (weights only) and refuses it, naming the node and the
field, if its modality or classes differ from the parameters: a graph that says it
classifies depth into four classes gets exactly that or does not start.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import msgspec
import torch
from msgspec import Meta

from messages.base import Header
from messages.errors import NodeError
from messages.types import ClassProbabilities, GraspState, ToFImage
from perception.classify.checkpoint import CheckpointError, Classifier
from perception.classify.preprocess import check_modality
from runtime.node import Node
from runtime.params import ExistingFile
from runtime.registry import register

# The shipped model, found from this file (not the working directory): a graph runs from anywhere.
DEFAULT_MODEL = str(Path(__file__).resolve().parents[1] / "models" / "tactile_resnet18.pt")
DEFAULT_CLASSES = ("mug", "pet_bottle", "square_bottle", "wine_glass")


class ClassifierParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of the classifier node."""

    model: Annotated[
        ExistingFile,
        Meta(
            description=(
                "checkpoint path (relative to the working directory, the repository root)."
            )
        ),
    ] = DEFAULT_MODEL
    modality: Annotated[
        str, Meta(description="``depth``, ``ir`` or ``both``; must be the checkpoint's.")
    ] = "both"
    classes: Annotated[
        tuple[str, ...], Meta(description="class names in label order; must be the checkpoint's.")
    ] = DEFAULT_CLASSES
    max_skew_secs: Annotated[
        float, Meta(ge=0, description="largest stamp difference of a left/right pair.")
    ] = 0.05
    min_period_secs: Annotated[
        float, Meta(ge=0, description="classify at most once per this period (0: every pair).")
    ] = 0.0
    threads: Annotated[
        int, Meta(ge=1, description="torch threads for inference (the graph shares few cores).")
    ] = 1

    def __post_init__(self) -> None:
        check_modality(self.modality)
        if not self.model:
            raise ValueError("`model` must be a checkpoint path, got ''")
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            raise ValueError(f"`classes` must be >= 2 distinct names, got {list(self.classes)}")


@register("classifier.resnet18")
class ResNet18ClassifierNode(Node):
    """Class probabilities of the grasped object, for stable grasps only."""

    Params = ClassifierParams
    inputs = {"left": ToFImage, "right": ToFImage, "grasp": GraspState}
    outputs = {"probabilities": ClassProbabilities}

    def setup(self) -> None:
        torch.set_num_threads(self.params.threads)
        try:
            self.classifier = Classifier.load(self.params.model)
        except CheckpointError as err:
            raise NodeError(f"{self.name}: params.model: {err}") from err
        meta = self.classifier.meta
        if meta.modality != self.params.modality:
            raise NodeError(
                f"{self.name}: params.modality is {self.params.modality!r} but checkpoint "
                f"{self.params.model} was trained on {meta.modality!r}"
            )
        if list(meta.classes) != list(self.params.classes):
            raise NodeError(
                f"{self.name}: params.classes is {list(self.params.classes)} but checkpoint "
                f"{self.params.model} has classes {list(meta.classes)} (names and order must match)"
            )
        self.stable_since_nanos: int | None = None
        self.latest: dict[str, ToFImage] = {}
        self.last_pair: tuple[int, int] | None = None
        self.last_publish_nanos: int | None = None

    def on_grasp(self, msg: GraspState) -> None:
        if msg.stable and self.stable_since_nanos is None:
            self.stable_since_nanos = msg.header.stamp_nanos
        elif not msg.stable:
            self.stable_since_nanos = None
            self.latest.clear()

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, port: str, msg: ToFImage) -> None:
        if msg.sensor and msg.sensor != port:
            self.io.log.warning("%s: image of sensor %r on port %r", self.name, msg.sensor, port)
        if self.stable_since_nanos is None or msg.header.stamp_nanos < self.stable_since_nanos:
            return
        self.latest[port] = msg
        if len(self.latest) < 2:
            return
        left, right = self.latest["left"], self.latest["right"]
        pair = (left.header.stamp_nanos, right.header.stamp_nanos)
        if pair == self.last_pair or abs(pair[0] - pair[1]) > self.params.max_skew_secs * 1e9:
            return
        stamp = max(pair)
        if (
            self.last_publish_nanos is not None
            and stamp - self.last_publish_nanos < self.params.min_period_secs * 1e9
        ):
            return
        self.last_pair = pair
        self.last_publish_nanos = stamp
        probs = self.classifier.classify(
            depth_left_m=left.depth_m,
            depth_right_m=right.depth_m,
            ir_left=left.ir,
            ir_right=right.ir,
        )
        classes = list(self.classifier.meta.classes)
        self.io.publish(
            "probabilities",
            ClassProbabilities(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                classes=classes,
                probabilities=probs,
                best=classes[int(probs.argmax())],
            ),
        )
