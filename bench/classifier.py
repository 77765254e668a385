"""Tactile classifier: accuracy against inference and training time.

Sweeps the knobs of the classifier (paper, tactile classification): modality (depth,
IR, both), input size (112 px, the shipped model's, or 64 px) and network width (half
or quarter of ResNet18's channels; the paper's 224 px full-width network is measured in
docs/classifier.md, too slow for a report that must end in 20 minutes). For each, a model is trained on the training dataset for a
fixed number of epochs (``train_secs``, on one thread), scored on a
held-out dataset of other grasps (``accuracy``, per frame), and timed at inference on
one core with batch 1 (``infer_ms_median``: the network; ``preprocess_ms_median``:
two frames to its input).

Data: the datasets the auto-labelling graph writes, ``CLASSIFIER_TRAIN`` and
``CLASSIFIER_TEST`` (environment; defaults ``out/datasets/autolabel_train`` and
``out/datasets/autolabel_test``). ``--quick`` (or missing datasets) uses a toy dataset
of ``perception.classify.synthetic`` at a tiny size instead, and says so in the ``data``
column.

    python -m bench.classifier [--quick] [--json]
"""

from __future__ import annotations

import io
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bench.common import Row, main, median, one_core, plain_log_ticks, progress
from perception.classify.checkpoint import Classifier
from perception.classify.dataset import load_samples, read_grasp, read_manifest
from perception.classify.preprocess import MODALITIES, InputSpec, frame_input
from perception.classify.synthetic import write_toy_dataset
from perception.classify.train import TrainConfig, predict, train

TRAIN_DIR = Path(os.environ.get("CLASSIFIER_TRAIN", "out/datasets/autolabel_train"))
TEST_DIR = Path(os.environ.get("CLASSIFIER_TEST", "out/datasets/autolabel_test"))


def _time_inference(classifier: Classifier, frame: dict[str, np.ndarray], repeats: int) -> tuple:
    """Median ms of preprocessing and of the forward pass, one thread, batch 1."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        x = frame_input(classifier.spec, **frame)[None]
        classifier.probabilities(x)  # warm-up: first call allocates
        pre, net = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            x = frame_input(classifier.spec, **frame)[None]
            mid = time.perf_counter()
            classifier.probabilities(x)
            end = time.perf_counter()
            pre.append((mid - start) * 1e3)
            net.append((end - mid) * 1e3)
        return median(pre), median(net)
    finally:
        torch.set_num_threads(threads)


def _first_frame(root: Path) -> dict[str, np.ndarray]:
    entry = read_manifest(root)["grasps"][0]
    arrays = read_grasp(root, entry)
    return {
        "depth_left_m": arrays["depth_left_m"][0].astype(np.float32),
        "depth_right_m": arrays["depth_right_m"][0].astype(np.float32),
        "ir_left": arrays["ir_left"][0],
        "ir_right": arrays["ir_right"][0],
    }


def run(quick: bool) -> list[Row]:
    one_core()  # training and inference on one thread: the machine is shared, figures compare
    with tempfile.TemporaryDirectory() as tmp:
        if quick or not (TRAIN_DIR.is_dir() and TEST_DIR.is_dir()):
            data = "toy"
            train_dir = write_toy_dataset(
                Path(tmp) / "train", grasps_per_class=4, frames_per_grasp=3, seed=0
            )
            test_dir = write_toy_dataset(
                Path(tmp) / "test", grasps_per_class=2, frames_per_grasp=3, seed=1
            )
        else:
            data, train_dir, test_dir = "autolabel", TRAIN_DIR, TEST_DIR
        if quick:
            grid = [(m, 32, w) for m in MODALITIES for w in (0.125, 0.0625)]
            epochs, frames_per_grasp, grasps, repeats = 4, None, None, 10
        else:
            # The same small budget for every setting: a fair comparison, not each
            # setting's best. Around the shipped model's 112 px at width 0.5 (a 224 px
            # full-width ResNet18 costs about 2 s per batch on two cores, so it is left to
            # ``perception.classify train``; the report must end in 20 minutes).
            grid = [(m, px, w) for m in MODALITIES for px in (112, 64) for w in (0.5, 0.25)]
            epochs, frames_per_grasp, grasps, repeats = 4, 2, 160, 30
        frame = _first_frame(test_dir)
        rows = []
        points = progress(grid, "bench.classifier", label=lambda g: f"{g[0]} {g[1]} px w{g[2]}")
        for modality, px, width in points:
            spec = InputSpec(modality=modality, input_px=px)
            samples = load_samples(
                train_dir, spec, max_frames_per_grasp=frames_per_grasp, max_grasps=grasps
            )
            held_out = load_samples(test_dir, spec, classes=samples.classes)
            config = TrainConfig(
                epochs=epochs,
                modality=modality,
                input_px=px,
                width=width,
                batch_size=16 if quick else 32,
                val_fraction=0.0,  # scored on the held-out set instead
                seed=0,
            )
            result = train(samples, config, progress_stream=io.StringIO())
            predicted, _ = predict(result.model, held_out.x)
            classifier = Classifier(result.model, result.meta)
            pre_ms, net_ms = _time_inference(classifier, frame, repeats)
            rows.append(
                {
                    "data": data,
                    "modality": modality,
                    "input_px": px,
                    "width": width,
                    "epochs": epochs,
                    "train_frames": int(len(samples.labels)),
                    "test_frames": int(len(held_out.labels)),
                    "accuracy": float((predicted == held_out.labels).mean()),
                    "infer_ms_median": net_ms,
                    "preprocess_ms_median": pre_ms,
                    "train_secs": result.train_secs,
                }
            )
        return rows


def plot(rows: list[Row], path: Path) -> None:
    """Accuracy against inference and training time: one legend entry per setting
    (marker: modality; colour: input size and width), no labels on the points, which
    pile up where settings score alike."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    markers = {"depth": "o", "ir": "s", "both": "^"}
    sizes = sorted({(r["input_px"], r["width"]) for r in rows}, reverse=True)
    colors = dict(zip(sizes, plt.get_cmap("tab10").colors, strict=False))
    for row in rows:
        style = {
            "marker": markers[row["modality"]],
            "color": colors[(row["input_px"], row["width"])],
            "s": 45,
            "alpha": 0.8,
        }
        label = f"{row['modality']:5} {row['input_px']:>3} px  width {row['width']:g}"
        for ax, key in zip(axes, ("infer_ms_median", "train_secs"), strict=True):
            ax.scatter(row[key], row["accuracy"], label=label if ax is axes[0] else None, **style)
    axes[0].set_xlabel("inference ms per frame (one core, batch 1)")
    axes[1].set_xlabel("training s")
    axes[0].set_ylabel("held-out accuracy")
    for ax in axes:
        plain_log_ticks(ax, "x")
        ax.grid(alpha=0.3)
    fig.legend(loc="center right", fontsize=8, prop={"family": "monospace", "size": 8})
    fig.suptitle(f"tactile classifier ({rows[0]['data'] if rows else ''} data)")
    fig.tight_layout(rect=(0, 0, 0.78, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main(
        "classifier",
        run,
        columns=[
            "data",
            "modality",
            "input_px",
            "width",
            "accuracy",
            "infer_ms_median",
            "preprocess_ms_median",
            "train_secs",
            "train_frames",
            "test_frames",
        ],
        plot=plot,
    )
