"""Training and evaluation of the tactile classifier (paper, tactile classification).

SGD with momentum and a cosine learning-rate schedule on a dataset of
:mod:`perception.classify.dataset`. The validation split is BY GRASP, stratified by
class: the frames of one grasp are nearly identical, so a split by frame would put
copies of training frames in the validation set and flatter the model.
"""

from __future__ import annotations

import copy
import io
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np
import torch
from torch import nn

from perception.classify.checkpoint import INPUT_FIELDS, ModelMeta, build_model
from perception.classify.dataset import Samples
from perception.classify.distributed import Group
from perception.classify.model import ResNet18
from perception.classify.preprocess import InputSpec, check_modality


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """Training knobs; every one is saved with the model."""

    epochs: int
    modality: str = "depth"
    input_px: int = 112
    width: float = 0.5
    batch_size: int = 32
    lr: float = 0.05
    momentum: float = 0.9
    weight_decay: float = 5e-4
    val_fraction: float = 0.3
    seed: int = 0
    shift_px: int = 4  # random translation (augmentation): grasps land a few px apart
    # Swap the two bubbles' halves of half the inputs (augmentation). The right finger is
    # the left one turned 180 degrees about the approach axis, cameras and printed
    # pattern alike (geometry/gripper.py), so the swapped pair is exactly what the hand
    # sees of the object turned that way: a grasp the generator draws just as often.
    swap_sides: bool = True
    max_frames_per_grasp: int | None = None
    subtract_mean: bool = True  # the network subtracts the mean training image first
    # Another membrane's imprint (augmentation; docs/classifier.md, "Membrane variation"):
    # each input's dent, its depth channel against the free bubble's input (``train``'s
    # ``free_input``), scaled by a factor drawn from [dent_scale_min, 1], its IR change
    # likewise from [ir_change_scale_min, 1], and its IR blurred by a Gaussian of sigma
    # drawn from [0, ir_blur_px] input pixels, each bubble's half on its own. 1, 1, 0: none.
    dent_scale_min: float = 1.0
    ir_change_scale_min: float = 1.0
    ir_blur_px: float = 0.0

    def __post_init__(self) -> None:
        check_modality(self.modality)
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")
        if self.batch_size < 2:
            raise ValueError(f"batch_size must be >= 2, got {self.batch_size}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if not 0 <= self.momentum < 1:
            raise ValueError(f"momentum must be in [0, 1), got {self.momentum}")
        if self.weight_decay < 0:
            raise ValueError(f"weight_decay must be >= 0, got {self.weight_decay}")
        if not 0 <= self.val_fraction < 1:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if self.shift_px < 0:
            raise ValueError(f"shift_px must be >= 0, got {self.shift_px}")
        if self.swap_sides and self.input_px % 2:
            # Left and right each fill half the columns only when input_px is even.
            raise ValueError(f"swap_sides needs an even input_px, got {self.input_px}")
        if self.max_frames_per_grasp is not None and self.max_frames_per_grasp < 1:
            raise ValueError(f"max_frames_per_grasp must be >= 1, got {self.max_frames_per_grasp}")
        for name in ("dent_scale_min", "ir_change_scale_min"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not self.ir_blur_px >= 0:
            raise ValueError(f"ir_blur_px must be >= 0, got {self.ir_blur_px}")
        if self.dent_scale_min < 1 and self.modality == "ir":
            raise ValueError("dent_scale_min varies the depth channel: modality 'ir' has none")
        if (self.ir_change_scale_min < 1 or self.ir_blur_px > 0) and self.modality == "depth":
            raise ValueError(
                "ir_change_scale_min and ir_blur_px vary the IR channel: modality 'depth' has none"
            )

    @property
    def scales_about_free(self) -> bool:
        """Whether the augmentation scales changes against the free bubble's input."""
        return self.dent_scale_min < 1 or self.ir_change_scale_min < 1


def split_by_grasp(
    grasp_ids: np.ndarray, labels: np.ndarray, val_fraction: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (train, val) over samples; every grasp's frames fall on one side.

    In each class, ``round(val_fraction * grasps)`` grasps (at least one when the class
    has two or more and ``val_fraction > 0``) are drawn for validation with ``seed``.
    """
    rng = np.random.default_rng(seed)
    val_grasps: list[int] = []
    for label in np.unique(labels):
        grasps = np.unique(grasp_ids[labels == label])
        count = int(round(val_fraction * len(grasps)))
        if val_fraction > 0 and len(grasps) >= 2:
            count = min(max(count, 1), len(grasps) - 1)
        val_grasps += rng.choice(grasps, size=count, replace=False).tolist()
    val = np.isin(grasp_ids, val_grasps)
    return ~val, val


def confusion_matrix(labels: np.ndarray, predicted: np.ndarray, num_classes: int) -> np.ndarray:
    """``(num_classes, num_classes)`` counts; row = true class, column = predicted."""
    matrix = np.zeros((num_classes, num_classes), dtype=np.int64)
    np.add.at(matrix, (labels, predicted), 1)
    return matrix


def format_confusion(matrix: np.ndarray, classes: Sequence[str]) -> str:
    """The confusion matrix as a text table (rows true, columns predicted)."""
    width = max(8, *(len(c) for c in classes)) + 1
    lines = ["true \\ predicted".ljust(width) + "".join(c.rjust(width) for c in classes)]
    for name, row in zip(classes, matrix, strict=True):
        lines.append(name.ljust(width) + "".join(str(int(v)).rjust(width) for v in row))
    total = matrix.sum()
    accuracy = np.trace(matrix) / total if total else float("nan")
    lines.append(f"accuracy {accuracy:.4f} ({int(np.trace(matrix))}/{int(total)})")
    return "\n".join(lines)


class Progress:
    """A text progress bar: redrawn in place on a terminal, a line per quarter otherwise."""

    def __init__(self, total: int, label: str, stream: IO[str] | None = None) -> None:
        self.total = max(total, 1)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.monotonic()
        self._last_quarter = -1

    def update(self, done: int, note: str = "") -> None:
        """Show ``done`` of ``total`` with a short note (loss, accuracy)."""
        fraction = min(done / self.total, 1.0)
        elapsed = time.monotonic() - self.start
        eta = elapsed / fraction - elapsed if fraction > 0 else float("nan")
        bar = "#" * int(fraction * 30)
        line = f"{self.label} [{bar:<30}] {done}/{self.total} {note} {elapsed:.0f}s eta {eta:.0f}s"
        if self.tty:
            self.stream.write("\r" + line)
            if done >= self.total:
                self.stream.write("\n")
        else:
            quarter = int(fraction * 4)
            if quarter == self._last_quarter:
                return
            self._last_quarter = quarter
            self.stream.write(line + "\n")
        self.stream.flush()


def _shifted(batch: torch.Tensor, shift_px: int, rng: np.random.Generator) -> torch.Tensor:
    """Each image moved by up to ``shift_px`` in x and y, zero-filled (augmentation)."""
    if shift_px == 0:
        return batch
    n, _, h, w = batch.shape
    padded = nn.functional.pad(batch, (shift_px,) * 4)
    offsets = rng.integers(0, 2 * shift_px + 1, size=(n, 2))
    return torch.stack(
        [padded[i, :, dy : dy + h, dx : dx + w] for i, (dy, dx) in enumerate(offsets)]
    )


def _sides_swapped(batch: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """Half the images (at random) with their left and right bubble halves swapped."""
    flip = torch.from_numpy(rng.random(len(batch)) < 0.5)
    if not flip.any():
        return batch
    out = batch.clone()
    out[flip] = torch.roll(batch[flip], batch.shape[-1] // 2, dims=-1)
    return out


def _membrane_varied(
    batch: torch.Tensor, free: torch.Tensor | None, config: TrainConfig, rng: np.random.Generator
) -> torch.Tensor:
    """Each input as another membrane might have made it (augmentation, ``TrainConfig``):
    its dent and IR change against ``free`` (the free bubble's input) scaled by a factor
    drawn per input, and its IR blurred, each bubble's half apart so that neither bleeds
    into the other. The depth channel is an affine map of depth and the resize is linear,
    so a scaled change in the input is the input of the same change scaled in metres
    (outside the clip at +-4 and holes, which a shallower dent fills: as on a membrane
    that does not reach the minimum range); the IR channel is standardised per frame, so
    there it is near, not exact."""
    depth = 0 if config.modality != "ir" else None
    ir = {"ir": 0, "both": 1}.get(config.modality)
    n = len(batch)
    out = batch
    for channel, low in ((depth, config.dent_scale_min), (ir, config.ir_change_scale_min)):
        if channel is None or low >= 1:
            continue
        assert free is not None  # train() checks it
        if out is batch:
            out = batch.clone()
        scale = torch.from_numpy(rng.uniform(low, 1.0, n).astype(np.float32))[:, None, None]
        base = free[channel]
        out[:, channel] = base + scale * (batch[:, channel] - base)
    if ir is not None and config.ir_blur_px > 0:
        if out is batch:
            out = batch.clone()
        sigmas = rng.uniform(0.0, config.ir_blur_px, n)
        half = out.shape[-1] // 2
        planes = out[:, ir].numpy()  # shares out's memory
        for i, sigma in enumerate(sigmas):
            for cols in (slice(0, half), slice(half, None)):
                side = np.ascontiguousarray(planes[i, :, cols])
                planes[i, :, cols] = cv2.GaussianBlur(
                    side, (0, 0), sigmaX=float(sigma), borderType=cv2.BORDER_REPLICATE
                )
    return out


@torch.inference_mode()
def predict(model: nn.Module, x: np.ndarray, batch_size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Predicted labels and softmax probabilities of ``model`` (put in eval mode) on ``x``."""
    model.eval()
    probs = []
    for start in range(0, len(x), batch_size):
        batch = torch.from_numpy(np.asarray(x[start : start + batch_size], dtype=np.float32))
        probs.append(torch.softmax(model(batch), dim=1).numpy())
    p = np.concatenate(probs) if probs else np.zeros((0, 0), np.float32)
    return p.argmax(axis=1) if len(p) else np.zeros(0, np.int64), p


@dataclass
class TrainResult:
    """A trained model and how it got there."""

    model: nn.Module
    meta: ModelMeta
    history: list[dict[str, float]]
    confusion: np.ndarray | None  # on the validation split, None without one
    train_secs: float
    split: dict[str, list[int]] = field(default_factory=dict)  # grasp ids per side


def train(
    samples: Samples,
    config: TrainConfig,
    *,
    progress_stream: IO[str] | None = None,
    on_epoch: Callable[[dict[str, float]], None] | None = None,
    training_record: dict[str, Any] | None = None,
    init: tuple[ResNet18, ModelMeta] | None = None,
    group: Group | None = None,
    spec: InputSpec | None = None,
    free_input: np.ndarray | None = None,
) -> TrainResult:
    """Train a ResNet18 on ``samples`` (inputs already of ``config``'s modality and size).

    With ``init`` (a trained model and its meta) training starts from its weights and
    keeps its mean image (the one its weights learnt with): fine-tuning on new data. The
    given model itself is left untouched.

    Args:
        samples: network inputs, labels and grasp ids (see ``dataset.load_samples``).
        config: the training knobs.
        progress_stream: where the progress bar goes (default stderr).
        on_epoch: called with each epoch's log record.
        training_record: extra facts stored in the model's meta (command, dataset).
        init: a model to start from, of ``config``'s modality, size and width and of the
            samples' classes.
        group: the training processes this one is part of (``distributed``): each
            computes its share of every batch; default alone.
        spec: the input the samples were made with (saved with the model); default
            ``config``'s modality and size with the default normalisation.
        free_input: the free bubble's frames as ``spec`` makes an input of them, which
            ``config``'s dent and IR change scales vary about (needed then only).

    Raises:
        ValueError: inputs whose channel count or size does not fit ``config``, an
            ``init`` model that does not fit ``config`` or the samples' classes, or a
            scale about the free bubble without ``free_input`` (or one of another shape).
    """
    spec = spec or InputSpec(modality=config.modality, input_px=config.input_px)
    if (spec.modality, spec.input_px) != (config.modality, config.input_px):
        raise ValueError(
            f"spec is {spec.modality!r} at {spec.input_px} px, config "
            f"{config.modality!r} at {config.input_px} px"
        )
    expected = (spec.channels, spec.input_px, spec.input_px)
    if samples.x.shape[1:] != expected:
        raise ValueError(f"samples have shape {samples.x.shape[1:]}, config needs {expected}")
    free = None
    if config.scales_about_free:
        if free_input is None or free_input.shape != expected:
            got = "none" if free_input is None else f"shape {free_input.shape}"
            raise ValueError(
                f"dent_scale_min and ir_change_scale_min scale about the free bubble's "
                f"input of shape {expected}: got {got}"
            )
        free = torch.from_numpy(np.asarray(free_input, dtype=np.float32))
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    train_mask, val_mask = split_by_grasp(
        samples.grasp_ids, samples.labels, config.val_fraction, config.seed
    )
    x_train, y_train = samples.x[train_mask], samples.labels[train_mask]
    x_val, y_val = samples.x[val_mask], samples.labels[val_mask]
    meta = ModelMeta.for_spec(spec, samples.classes, config.width)
    if init is not None:
        check_init(init[1], meta)
        model = copy.deepcopy(init[0])  # the caller's model stays as it was
    else:
        model = build_model(meta)
    if init is None and config.subtract_mean and len(x_train):
        # The mean training image, in float64 chunks (the inputs are float16).
        total = np.zeros(x_train.shape[1:], np.float64)
        for first in range(0, len(x_train), 256):
            total += x_train[first : first + 256].astype(np.float64).sum(axis=0)
        model.input_mean.copy_(torch.from_numpy((total / len(x_train)).astype(np.float32)))
    optimizer = torch.optim.SGD(
        model.parameters(),
        lr=config.lr,
        momentum=config.momentum,
        weight_decay=config.weight_decay,
        nesterov=config.momentum > 0,
    )
    steps_per_epoch = math.ceil(len(x_train) / config.batch_size)
    total_steps = steps_per_epoch * config.epochs
    warmup = min(steps_per_epoch, max(1, total_steps // 10))

    def lr_at(step: int) -> float:
        # Linear warm-up, then cosine decay to zero: robust without tuning per size.
        if step < warmup:
            return config.lr * (step + 1) / warmup
        t = (step - warmup) / max(1, total_steps - warmup)
        return config.lr * 0.5 * (1 + math.cos(math.pi * t))

    group = group or Group()
    stepper = group.wrap(model)  # the model as the steps call it (DDP in a group)
    if not group.leader:
        progress_stream = io.StringIO()  # one progress bar: the leader's
    loss_fn = nn.CrossEntropyLoss()
    history: list[dict[str, float]] = []
    start = time.monotonic()
    step = 0
    for epoch in range(1, config.epochs + 1):
        model.train()
        order = rng.permutation(len(x_train))
        bar = Progress(steps_per_epoch, f"epoch {epoch}/{config.epochs}", progress_stream)
        # Floats: the group sums them across processes (group.total).
        loss_sum, correct, seen = 0.0, 0.0, 0.0
        epoch_start = time.monotonic()
        for batch_index in range(steps_per_epoch):
            idx = np.sort(
                order[batch_index * config.batch_size : (batch_index + 1) * config.batch_size]
            )
            if len(idx) < 2 * group.size:  # batch norm needs two samples per process
                continue
            xb = torch.from_numpy(x_train[idx].astype(np.float32))
            # The whole batch is augmented in every process, so that all draw the same
            # numbers and stay in step; each then keeps its share. The membrane's variation
            # first: it scales about the free bubble, whose sides are not swapped.
            xb = _membrane_varied(xb, free, config, rng)
            if config.swap_sides:
                xb = _sides_swapped(xb, rng)
            xb = _shifted(xb, config.shift_px, rng)
            mine = group.shard(np.arange(len(idx)))
            xb, yb = xb[mine], torch.from_numpy(y_train[idx][mine])
            for params in optimizer.param_groups:
                params["lr"] = lr_at(step)
            logits = stepper(xb)
            loss = loss_fn(logits, yb)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            step += 1
            loss_sum += float(loss.detach()) * len(yb)
            correct += int((logits.argmax(1) == yb).sum())
            seen += len(yb)
            bar.update(batch_index + 1, f"loss {loss_sum / seen:.4f} acc {correct / seen:.3f}")
        epoch_secs = time.monotonic() - epoch_start
        loss_sum, correct, seen = group.total([loss_sum, correct, seen])
        record: dict[str, float] = {
            "epoch": epoch,
            "train_loss": loss_sum / max(seen, 1),
            "train_accuracy": correct / max(seen, 1),
            "lr": lr_at(max(step - 1, 0)),
            "epoch_secs": epoch_secs,
            "samples_per_sec": seen / max(epoch_secs, 1e-9),
            "processes": group.size,
        }
        if len(x_val):
            predicted, probs = predict(model, x_val)
            picked = probs[np.arange(len(y_val)), y_val]
            record["val_loss"] = float(-np.log(np.clip(picked, 1e-12, 1)).mean())
            record["val_accuracy"] = float((predicted == y_val).mean())
        history.append(record)
        if on_epoch is not None:
            on_epoch(record)
    train_secs = time.monotonic() - start
    confusion = None
    if len(x_val):
        predicted, _ = predict(model, x_val)
        confusion = confusion_matrix(y_val, predicted, len(samples.classes))
    split = {
        "train_grasps": sorted(int(g) for g in np.unique(samples.grasp_ids[train_mask])),
        "val_grasps": sorted(int(g) for g in np.unique(samples.grasp_ids[val_mask])),
    }
    record_out = {
        "config": {k: v for k, v in asdict(config).items() if v is not None},
        "train_frames": int(len(x_train)),
        "val_frames": int(len(x_val)),
        "val_grasps": split["val_grasps"],
        "train_secs": round(train_secs, 1),
        "final": history[-1] if history else {},
        **(training_record or {}),
    }
    if confusion is not None:
        record_out["val_confusion"] = confusion.tolist()
    # Round trip through JSON: the meta must hold only plain types (weights_only loading).
    meta = ModelMeta.for_spec(
        spec, samples.classes, config.width, json.loads(json.dumps(record_out))
    )
    model.eval()
    return TrainResult(model, meta, history, confusion, train_secs, split)


def check_init(init: ModelMeta, wanted: ModelMeta) -> None:
    """Refuse to fine-tune a model (``init``) whose classes or inputs differ from ``wanted``.

    The depth an invalid pixel stands for and the imprint scale may differ: a fine-tune
    may move a model to another reading of its frames (the saved model carries the new
    one).

    Raises:
        ValueError: naming the first field that differs.
    """
    movable = ("invalid_depth_m", "imprint_depth_m", "imprint_ir")
    for name in (n for n in INPUT_FIELDS if n not in movable):
        have, need = getattr(init, name), getattr(wanted, name)
        if have != need:
            raise ValueError(f"init model has {name} {have!r}, the training needs {need!r}")


def append_log(path: str | Path, record: dict[str, Any]) -> None:
    """Append one JSON line to a log file."""
    with Path(path).open("a") as stream:
        stream.write(json.dumps(record) + "\n")
