"""Saving and loading a trained classifier, and running it on frames.

A checkpoint is a plain dictionary of tensors, strings and numbers, saved with
``torch.save`` and read back with ``torch.load(..., weights_only=True)`` (no pickle of
project classes, so a checkpoint cannot run code). Besides the weights it carries what
a user of the model must agree with: the class names in label order, the modality, the
input size, the width multiplier and the depth normalisation (with the depth an invalid
pixel stands for; a checkpoint saved before that was stored reads it as the centre, as
its model was trained), the imprint scale and the free bubble's frames it is measured
against, if the model was trained so (``preprocess``; a checkpoint without them reads
frames unscaled), plus a free ``training`` record (command, seed, dataset manifest
digest, accuracy).

Weights may be stored in half precision (``half=True``) to halve the file; they are
turned back to float32 on load, where inference runs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from perception.classify.model import ResNet18
from perception.classify.preprocess import FREE_FIELDS, FreeBubble, InputSpec, frame_input

FORMAT = "softbubble-classifier"
VERSION = 1


# What two models must share to be averaged: classes and everything about their inputs.
INPUT_FIELDS = (
    "classes",
    "modality",
    "input_px",
    "width",
    "depth_center_m",
    "depth_scale_m",
    "invalid_depth_m",
    "imprint_depth_m",
    "imprint_ir",
)


class CheckpointError(ValueError):
    """A checkpoint file is not a classifier of this format, or does not fit its use."""


@dataclass(frozen=True, kw_only=True)
class ModelMeta:
    """Everything about a trained model except its weights."""

    classes: tuple[str, ...]
    modality: str
    input_px: int
    width: float
    depth_center_m: float
    depth_scale_m: float
    invalid_depth_m: float
    imprint_depth_m: float = 0.0
    imprint_ir: float = 0.0
    free: FreeBubble | None = field(default=None, compare=False, repr=False)
    training: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            raise ValueError(f"classes must be >= 2 distinct names, got {list(self.classes)}")
        if not self.width > 0:
            raise ValueError(f"width must be > 0, got {self.width}")
        self.spec  # noqa: B018 - checks modality, input_px and the depth scale

    @property
    def spec(self) -> InputSpec:
        return InputSpec(
            modality=self.modality,
            input_px=self.input_px,
            depth_center_m=self.depth_center_m,
            depth_scale_m=self.depth_scale_m,
            invalid_depth_m=self.invalid_depth_m,
            imprint_depth_m=self.imprint_depth_m,
            imprint_ir=self.imprint_ir,
            free=self.free,
        )

    @classmethod
    def for_spec(
        cls,
        spec: InputSpec,
        classes: Sequence[str],
        width: float,
        training: Mapping[str, Any] | None = None,
    ) -> ModelMeta:
        """Meta of a model trained on inputs of ``spec``."""
        return cls(
            classes=tuple(classes),
            modality=spec.modality,
            input_px=spec.input_px,
            width=width,
            depth_center_m=spec.depth_center_m,
            depth_scale_m=spec.depth_scale_m,
            invalid_depth_m=spec.invalid_depth_m,
            imprint_depth_m=spec.imprint_depth_m,
            imprint_ir=spec.imprint_ir,
            free=spec.free,
            training=dict(training or {}),
        )


def build_model(meta: ModelMeta) -> ResNet18:
    """An untrained network of the shape ``meta`` describes."""
    return ResNet18(
        len(meta.classes), in_channels=meta.spec.channels, width=meta.width, input_px=meta.input_px
    )


def save_checkpoint(
    path: str | Path, model: torch.nn.Module, meta: ModelMeta, *, half: bool
) -> None:
    """Write ``model`` and ``meta`` to ``path`` (weights in float16 if ``half``)."""
    state = {}
    for name, tensor in model.state_dict().items():
        tensor = tensor.detach().cpu()
        if half and tensor.is_floating_point():
            tensor = tensor.half()
        state[name] = tensor.clone()
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "classes": list(meta.classes),
        "modality": meta.modality,
        "input_px": int(meta.input_px),
        "width": float(meta.width),
        "depth_center_m": float(meta.depth_center_m),
        "depth_scale_m": float(meta.depth_scale_m),
        "invalid_depth_m": float(meta.invalid_depth_m),
        "training": dict(meta.training),
        "state_dict": state,
    }
    if meta.imprint_depth_m > 0 and meta.free is not None:
        payload["imprint_depth_m"] = float(meta.imprint_depth_m)
        payload["imprint_ir"] = float(meta.imprint_ir)
        payload["free_bubble"] = {
            n: torch.from_numpy(getattr(meta.free, n).astype(np.float16)) for n in FREE_FIELDS
        }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def free_bubble(tensors: Mapping[str, torch.Tensor] | None, where: str) -> FreeBubble | None:
    """A checkpoint's free-bubble frames (None if it has none).

    Raises:
        ValueError: a missing frame or one not a tensor, naming ``where``.
    """
    if tensors is None:
        return None
    if not isinstance(tensors, Mapping) or not all(
        isinstance(tensors.get(n), torch.Tensor) for n in FREE_FIELDS
    ):
        raise ValueError(f"{where}: free_bubble must hold the tensors {list(FREE_FIELDS)}")
    return FreeBubble.from_arrays({n: tensors[n].float().numpy() for n in FREE_FIELDS}, where)


def load_checkpoint(path: str | Path) -> tuple[ResNet18, ModelMeta]:
    """The model (float32, eval mode) and its meta from a checkpoint file.

    Raises:
        CheckpointError: missing file, not a classifier checkpoint, or weights that do not
            fit the network the meta describes.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for a bad or unsafe file
        raise CheckpointError(f"{path}: cannot load as a weights-only checkpoint: {err}") from err
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a {FORMAT} checkpoint")
    if payload.get("version") != VERSION:
        raise CheckpointError(f"{path}: version {payload.get('version')}, expected {VERSION}")
    try:
        meta = ModelMeta(
            classes=tuple(payload["classes"]),
            modality=payload["modality"],
            input_px=int(payload["input_px"]),
            width=float(payload["width"]),
            depth_center_m=float(payload["depth_center_m"]),
            depth_scale_m=float(payload["depth_scale_m"]),
            # Saved before invalid pixels had a depth of their own: they were the centre.
            invalid_depth_m=float(payload.get("invalid_depth_m") or payload["depth_center_m"]),
            # Saved before imprints were scaled: frames unscaled, as the model was trained.
            imprint_depth_m=float(payload.get("imprint_depth_m", 0.0)),
            imprint_ir=float(payload.get("imprint_ir", 0.0)),
            free=free_bubble(payload.get("free_bubble"), str(path)),
            training=payload.get("training", {}),
        )
    except (KeyError, ValueError) as err:
        raise CheckpointError(f"{path}: bad meta: {err}") from err
    model = build_model(meta)
    state = {
        name: t.float() if t.is_floating_point() else t for name, t in payload["state_dict"].items()
    }
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        raise CheckpointError(f"{path}: weights do not fit the network: {err}") from err
    model.eval()
    return model, meta


def average(
    models: Sequence[tuple[ResNet18, ModelMeta]], weights: Sequence[float] | None = None
) -> ResNet18:
    """A network whose weights are the weighted mean of ``models``' (uniform by default).

    Every floating-point tensor of the state (weights, batch-norm statistics, the mean
    image) is ``sum(w_i * model_i) / sum(w_i)``; counters are the last model's. Meant for
    fine-tunes of one start and the start itself (same shape, same basin): the mean keeps
    more of what the start knew and gains most of what each fine-tune learnt
    (weight-space ensembling: Wortsman et al. 2022, "Model soups" and "Robust
    fine-tuning of zero-shot models"). The given models do not change.

    Raises:
        CheckpointError: no model, a weight count that differs from the model count, a
            negative weight or all zero, or models of different classes, inputs or width.
    """
    if not models:
        raise CheckpointError("average needs at least one model")
    w = [1.0] * len(models) if weights is None else [float(v) for v in weights]
    if len(w) != len(models):
        raise CheckpointError(f"{len(w)} weights for {len(models)} models")
    if min(w) < 0 or not sum(w) > 0:
        raise CheckpointError(f"weights must be >= 0 and not all zero, got {w}")
    first = models[0][1]
    for _, meta in models[1:]:
        for name in INPUT_FIELDS:
            a, b = getattr(first, name), getattr(meta, name)
            if a != b:
                raise CheckpointError(f"the models differ in {name}: {a!r} and {b!r}")
        if first.free is not None and not first.free.same(meta.free):
            raise CheckpointError("the models differ in their free-bubble frames")
    states = [m.state_dict() for m, _ in models]
    share = [v / sum(w) for v in w]
    mixed = {
        k: sum(f * state[k] for f, state in zip(share, states, strict=True))
        if v.is_floating_point()
        else v.clone()
        for k, v in states[-1].items()
    }
    model = build_model(models[-1][1])
    model.load_state_dict(mixed)
    model.eval()
    return model


class Classifier:
    """A trained model ready for frames: preprocessing, forward pass, softmax.

    Args:
        model: the network (put in eval mode here).
        meta: its classes and input spec.
    """

    def __init__(self, model: torch.nn.Module, meta: ModelMeta) -> None:
        self.model = model.eval()
        self.meta = meta
        self.spec = meta.spec

    @classmethod
    def load(cls, path: str | Path) -> Classifier:
        """A classifier from a checkpoint file (see :func:`load_checkpoint`)."""
        return cls(*load_checkpoint(path))

    @torch.inference_mode()
    def probabilities(self, x: np.ndarray) -> np.ndarray:
        """Class probabilities ``(N, classes)`` for inputs ``(N, C, px, px)``."""
        logits = self.model(torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)))
        return torch.softmax(logits, dim=1).numpy()

    def classify(
        self,
        *,
        depth_left_m: np.ndarray | None = None,
        depth_right_m: np.ndarray | None = None,
        ir_left: np.ndarray | None = None,
        ir_right: np.ndarray | None = None,
    ) -> np.ndarray:
        """Probabilities ``(classes,)`` float32 for one frame pair."""
        x = frame_input(
            self.spec,
            depth_left_m=depth_left_m,
            depth_right_m=depth_right_m,
            ir_left=ir_left,
            ir_right=ir_right,
        )
        probabilities: np.ndarray = self.probabilities(x[None])[0].astype(np.float32)
        return probabilities
