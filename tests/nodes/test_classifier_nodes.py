"""The classifier node: stable grasps only, pairing, and refusing mismatched checkpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from messages.base import Header
from messages.errors import NodeError
from messages.types import GraspState, ToFImage
from nodes.classifier import ResNet18ClassifierNode
from perception.classify.checkpoint import ModelMeta, build_model, save_checkpoint
from perception.classify.preprocess import InputSpec
from runtime.testing import feed, make_node

CLASSES = ["mug", "pet_bottle", "square_bottle", "wine_glass"]
MS = 1_000_000


def _checkpoint(path: Path, modality: str = "depth", classes: list[str] = CLASSES) -> Path:
    meta = ModelMeta.for_spec(InputSpec(modality=modality, input_px=32), classes, 0.125)
    save_checkpoint(path, build_model(meta), meta, half=True)
    return path


def _image(sensor: str, stamp_ms: int) -> ToFImage:
    rng = np.random.default_rng(stamp_ms)
    return ToFImage(
        header=Header(stamp_nanos=stamp_ms * MS, frame_id=f"{sensor}_sensor"),
        sensor=sensor,
        depth_m=(0.08 + rng.normal(0, 1e-3, (12, 16))).astype(np.float32),
        ir=rng.integers(100, 3000, (12, 16)).astype(np.uint16),
        fx_px=10.0,
        fy_px=10.0,
        cx_px=8.0,
        cy_px=6.0,
    )


def _grasp(stable: bool, stamp_ms: int) -> GraspState:
    return GraspState(header=Header(stamp_nanos=stamp_ms * MS), stable=stable)


@pytest.fixture
def node(tmp_path: Path):
    path = _checkpoint(tmp_path / "m.pt")
    return make_node(ResNet18ClassifierNode, {"model": str(path)}, name="classifier")


def test_publishes_for_stable_grasps_only(node) -> None:
    node, io = node
    feed(node, "left", _image("left", 0))
    feed(node, "right", _image("right", 0))
    assert io.published["probabilities"] == []  # no grasp yet
    feed(node, "grasp", _grasp(True, 10))
    feed(node, "left", _image("left", 5))  # taken before the grasp was stable
    feed(node, "right", _image("right", 5))
    assert io.published["probabilities"] == []
    feed(node, "left", _image("left", 20))
    feed(node, "right", _image("right", 21))
    feed(node, "left", _image("left", 40))
    out = io.published["probabilities"]
    assert len(out) == 2  # pairs (20, 21) and (40, 21)
    assert out[0].classes == CLASSES
    assert out[0].probabilities.shape == (4,)
    assert abs(float(out[0].probabilities.sum()) - 1) < 1e-5
    assert out[0].best == CLASSES[int(out[0].probabilities.argmax())]
    assert out[0].header.stamp_nanos == 21 * MS
    feed(node, "grasp", _grasp(False, 50))
    feed(node, "left", _image("left", 60))
    feed(node, "right", _image("right", 60))
    assert len(io.published["probabilities"]) == 2


def test_pairs_too_far_apart_are_skipped(tmp_path: Path) -> None:
    path = _checkpoint(tmp_path / "m.pt")
    node, io = make_node(
        ResNet18ClassifierNode, {"model": str(path), "max_skew_secs": 0.01}, name="c"
    )
    feed(node, "grasp", _grasp(True, 0))
    feed(node, "left", _image("left", 10))
    feed(node, "right", _image("right", 30))
    assert io.published["probabilities"] == []
    feed(node, "left", _image("left", 35))
    assert len(io.published["probabilities"]) == 1


def test_refuses_checkpoint_of_other_modality(tmp_path: Path) -> None:
    path = _checkpoint(tmp_path / "ir.pt", modality="ir")
    with pytest.raises(NodeError, match=r"classifier: params\.modality is 'depth'.*'ir'"):
        make_node(ResNet18ClassifierNode, {"model": str(path)}, name="classifier")
    node, _ = make_node(
        ResNet18ClassifierNode, {"model": str(path), "modality": "ir"}, name="classifier"
    )
    assert node.classifier.meta.modality == "ir"


def test_refuses_checkpoint_of_other_classes(tmp_path: Path) -> None:
    path = _checkpoint(tmp_path / "three.pt", classes=["mug", "pet_bottle", "can"])
    with pytest.raises(NodeError, match=r"classifier: params\.classes .* has classes"):
        make_node(ResNet18ClassifierNode, {"model": str(path)}, name="classifier")
    swapped = _checkpoint(tmp_path / "swapped.pt", classes=CLASSES[::-1])
    with pytest.raises(NodeError, match=r"params\.classes"):
        make_node(ResNet18ClassifierNode, {"model": str(swapped)}, name="classifier")


def test_missing_checkpoint_names_the_field(tmp_path: Path) -> None:
    with pytest.raises(NodeError, match=r"classifier: params\.model: .*no such checkpoint"):
        make_node(ResNet18ClassifierNode, {"model": str(tmp_path / "none.pt")}, name="classifier")


def test_bad_params_are_refused() -> None:
    with pytest.raises(ValueError, match="modality"):
        make_node(ResNet18ClassifierNode, {"modality": "rgb"})
    with pytest.raises(ValueError, match="classes"):
        make_node(ResNet18ClassifierNode, {"classes": ["mug"]})
