"""Tactile object classification (paper, "Tactile object classification").

ResNet18 on the two bubbles' images side by side (depth, IR or both as channels),
trained on datasets the auto-labelling graph writes. Modules:

* :mod:`.model`: the network (width multiplier knob).
* :mod:`.preprocess`: frames to the network's input (modality, input size).
* :mod:`.dataset`: the on-disk format (``.npz`` per grasp, JSON manifest), writer, loader.
* :mod:`.train`: SGD training with a by-grasp validation split, confusion matrix.
* :mod:`.checkpoint`: weights-only checkpoints carrying classes, modality, size, width;
  :class:`Classifier` for inference.
* :mod:`.autolabel`: the random grasp generator of the auto-labelling supervisor.
* ``python -m perception.classify``: ``train``, ``evaluate``, ``info``.
"""

from __future__ import annotations

from perception.classify.checkpoint import (
    CheckpointError,
    Classifier,
    ModelMeta,
    load_checkpoint,
    save_checkpoint,
)
from perception.classify.dataset import (
    DatasetError,
    DatasetWriter,
    GraspBuffer,
    load_samples,
    read_manifest,
)
from perception.classify.model import ResNet18
from perception.classify.preprocess import MODALITIES, InputSpec, frame_input
from perception.classify.train import TrainConfig, confusion_matrix, split_by_grasp, train

__all__ = [
    "MODALITIES",
    "CheckpointError",
    "Classifier",
    "DatasetError",
    "DatasetWriter",
    "GraspBuffer",
    "InputSpec",
    "ModelMeta",
    "ResNet18",
    "TrainConfig",
    "confusion_matrix",
    "frame_input",
    "load_checkpoint",
    "load_samples",
    "read_manifest",
    "save_checkpoint",
    "split_by_grasp",
    "train",
]
