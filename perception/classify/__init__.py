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

import importlib
from typing import Any

# Names re-exported from the submodules, imported on first use (PEP 562): the grasp
# generator and the dataset format need no torch, and a node that imports them should
# not pay seconds of start-up for it.
_EXPORTS = {
    "CheckpointError": "checkpoint",
    "Classifier": "checkpoint",
    "ModelMeta": "checkpoint",
    "load_checkpoint": "checkpoint",
    "save_checkpoint": "checkpoint",
    "DatasetError": "dataset",
    "DatasetWriter": "dataset",
    "GraspBuffer": "dataset",
    "load_samples": "dataset",
    "read_manifest": "dataset",
    "ResNet18": "model",
    "MODALITIES": "preprocess",
    "InputSpec": "preprocess",
    "frame_input": "preprocess",
    "TrainConfig": "train",
    "confusion_matrix": "train",
    "split_by_grasp": "train",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
