"""Command line of the tactile classifier.

    python -m perception.classify train DATASET [DATASET ...] --epochs E --out model.pt [knobs]
    python -m perception.classify evaluate MODEL DATASET [--json] [--end-mm 15]
    python -m perception.classify info DATASET
    python -m perception.classify average MODEL [MODEL ...] [--weights W ...] --out model.pt

``train`` prints a progress bar (stderr), one log line per epoch (stdout, and as JSON
lines in ``--log``, default ``OUT.log.jsonl``) and the confusion matrix of the
validation split (30% of the grasps, by grasp) at the end; several datasets (of the same
classes) train as one; ``--init MODEL`` fine-tunes a trained model on them. ``evaluate``
scores a saved model on a held-out dataset: the confusion matrix, the accuracy per grasp,
apart for grasps held within ``--end-mm`` of an object's end (where the objects look most
alike), and the grasps it gets wrong. ``average`` writes the model whose weights are the (weighted) mean
of several, a start and its fine-tunes (``checkpoint.average``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from perception.classify.autolabel import end_distance_m
from perception.classify.checkpoint import (
    ModelMeta,
    average,
    load_checkpoint,
    save_checkpoint,
)
from perception.classify.dataset import (
    MANIFEST,
    Samples,
    concat_samples,
    load_samples,
    read_manifest,
)
from perception.classify.distributed import join_from_env, leave
from perception.classify.preprocess import (
    FREE_FIELDS,
    MODALITIES,
    FreeBubble,
    InputSpec,
    frame_input,
)
from perception.classify.train import (
    TrainConfig,
    append_log,
    check_init,
    confusion_matrix,
    format_confusion,
    predict,
    train,
)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _free_bubble(args: argparse.Namespace) -> FreeBubble | None:
    """The free bubble's frames of ``--free-bubble``, None without it.

    Raises:
        ValueError: a file without the frames (naming the file).
    """
    if args.free_bubble is None:
        return None
    with np.load(args.free_bubble, allow_pickle=False) as arrays:
        return FreeBubble.from_arrays(dict(arrays), args.free_bubble)


def _imprint(args: argparse.Namespace, free: FreeBubble | None) -> dict[str, Any]:
    """The imprint scale's fields of the input spec from ``--imprint-depth-mm`` and
    ``--imprint-ir`` (both or neither) against ``free``.

    Raises:
        ValueError: one size without the other, or the sizes without the free bubble.
    """
    sizes = [args.imprint_depth_mm, args.imprint_ir]
    if all(v is None for v in sizes):
        return {}
    if any(v is None for v in sizes) or free is None:
        raise ValueError("--free-bubble, --imprint-depth-mm and --imprint-ir go together")
    return {
        "imprint_depth_m": args.imprint_depth_mm / 1000.0,
        "imprint_ir": float(args.imprint_ir),
        "free": free,
    }


def _cmd_train(args: argparse.Namespace) -> int:
    group = join_from_env()  # under torchrun: one of several processes (distributed.py)
    say = print if group.leader else (lambda *_, **__: None)
    config = TrainConfig(
        epochs=args.epochs,
        modality=args.modality,
        input_px=args.input_px,
        width=args.width,
        batch_size=args.batch_size,
        lr=args.lr,
        momentum=args.momentum,
        weight_decay=args.weight_decay,
        val_fraction=args.val_fraction,
        seed=args.seed,
        shift_px=args.shift_px,
        swap_sides=not args.no_swap_sides,
        max_frames_per_grasp=args.max_frames_per_grasp,
        subtract_mean=not args.no_mean,
        dent_scale_min=args.dent_scale_min,
        ir_change_scale_min=args.ir_change_scale_min,
        ir_blur_px=args.ir_blur_px,
    )
    free = _free_bubble(args)
    spec = InputSpec(modality=config.modality, input_px=config.input_px, **_imprint(args, free))
    if free is not None and not spec.imprint_depth_m and not config.scales_about_free:
        raise ValueError(
            "--free-bubble is for the imprint scale (--imprint-depth-mm, --imprint-ir) "
            "or the membrane's variation (--dent-scale-min, --ir-change-scale-min)"
        )
    if config.scales_about_free and free is None:
        raise ValueError(
            "--dent-scale-min and --ir-change-scale-min scale about the free bubble: "
            "give --free-bubble"
        )
    free_input = (
        frame_input(spec, **{name: getattr(free, name) for name in FREE_FIELDS})
        if free is not None
        else None
    )
    init = load_checkpoint(args.init) if args.init else None
    if init is not None:  # before the datasets load (minutes): its inputs must fit
        check_init(init[1], ModelMeta.for_spec(spec, init[1].classes, config.width))
    started = time.monotonic()
    parts: list[Samples] = []
    sources: list[dict[str, Any]] = []
    for name in args.dataset:
        root = Path(name)
        manifest = read_manifest(root)
        part = load_samples(
            root,
            spec,
            # A fine-tune keeps the start's label order.
            classes=parts[0].classes if parts else (init[1].classes if init else None),
            max_frames_per_grasp=config.max_frames_per_grasp,
        )
        say(
            f"dataset {root}: {len(manifest['grasps'])} grasps, {len(part.labels)} frames, "
            f"classes {part.classes}"
        )
        parts.append(part)
        sources.append(
            {
                "path": str(root),
                "manifest_sha256": _sha256(root / MANIFEST),
                "seeds": manifest.get("seeds", {}),
                "counts_per_class": manifest.get("counts_per_class", {}),
            }
        )
    samples = concat_samples(parts)
    say(f"{len(samples.labels)} frames loaded in {time.monotonic() - started:.1f}s")
    log_path = Path(args.log) if args.log else Path(str(args.out) + ".log.jsonl")
    log_path.parent.mkdir(parents=True, exist_ok=True)
    log_path.write_text("")

    def on_epoch(record: dict[str, float]) -> None:
        print(
            "epoch {epoch}: train loss {train_loss:.4f} acc {train_accuracy:.4f}".format(**record)
            + (
                " | val loss {val_loss:.4f} acc {val_accuracy:.4f}".format(**record)
                if "val_accuracy" in record
                else ""
            )
            + f" | {record['epoch_secs']:.0f}s",
            flush=True,
        )
        append_log(log_path, record)

    record: dict[str, Any] = {
        "command": "python -m perception.classify " + shlex.join(args.argv),
        "datasets": sources,
        "torch": torch.__version__,
    }
    if init is not None:
        record["init"] = {
            "path": args.init,
            "sha256": _sha256(Path(args.init)),
            "training": dict(init[1].training),  # the start's own history, nested
        }
    record["processes"] = group.size
    try:
        result = train(
            samples,
            config,
            on_epoch=on_epoch if group.leader else None,
            training_record=record,
            init=init,
            group=group,
            spec=spec,
            free_input=free_input,
        )
    finally:
        leave(group)
    if not group.leader:
        return 0
    save_checkpoint(args.out, result.model, result.meta, half=not args.full_precision)
    print(f"trained in {result.train_secs:.0f}s on {group.size} process(es); saved {args.out}")
    if result.confusion is not None:
        print("validation confusion matrix (by grasp split):")
        print(format_confusion(result.confusion, samples.classes))
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    if not args.end_mm > 0:
        raise ValueError(f"--end-mm must be > 0, got {args.end_mm}")
    if args.threads:
        torch.set_num_threads(args.threads)
    model, meta = load_checkpoint(args.model)
    samples = load_samples(
        args.dataset,
        meta.spec,
        classes=meta.classes,
        max_frames_per_grasp=args.max_frames_per_grasp,
    )
    predicted, _ = predict(model, samples.x)
    matrix = confusion_matrix(samples.labels, predicted, len(meta.classes))
    accuracy = float(np.trace(matrix) / matrix.sum())
    # A grasp is right when the majority of its frames is: what a task acting once per
    # grasp would see.
    params = {
        int(g["grasp_id"]): g.get("params", {}) for g in read_manifest(args.dataset)["grasps"]
    }
    near_m = args.end_mm / 1000
    regions: dict[str, list[int]] = {"near_end": [], "body": []}
    grasp_correct, wrong = [], []
    for grasp in np.unique(samples.grasp_ids):
        mask = samples.grasp_ids == grasp
        votes = np.bincount(predicted[mask], minlength=len(meta.classes))
        truth = int(samples.labels[mask][0])
        correct = int(votes.argmax() == truth)
        grasp_correct.append(correct)
        p = params.get(int(grasp), {})
        end_m = None
        if "object_name" in p and "height_m" in p:  # auto-labelled: where the grasp was
            end_m = end_distance_m(p["object_name"], p["height_m"], p.get("variant"))
            regions["near_end" if end_m < near_m else "body"].append(correct)
        if not correct:
            wrong.append(
                (int(grasp), meta.classes[truth], meta.classes[int(votes.argmax())], end_m)
            )
    by_region = {
        name: {"grasps": len(v), "grasp_accuracy": float(np.mean(v))}
        for name, v in regions.items()
        if v
    }
    if args.json:
        json.dump(
            {
                "model": str(args.model),
                "dataset": str(args.dataset),
                "classes": list(meta.classes),
                "frames": int(matrix.sum()),
                "accuracy": accuracy,
                "grasps": len(grasp_correct),
                "grasp_accuracy": float(np.mean(grasp_correct)),
                "confusion": matrix.tolist(),
                "end_mm": args.end_mm,
                "by_region": by_region,
                "wrong_grasps": [
                    {"grasp_id": g, "true": t, "predicted": pr, "end_distance_m": e}
                    for g, t, pr, e in wrong
                ],
            },
            sys.stdout,
        )
        sys.stdout.write("\n")
    else:
        print(
            f"model {args.model} ({meta.modality}, {meta.input_px} px, width {meta.width}) "
            f"on {args.dataset}: {len(grasp_correct)} grasps, {int(matrix.sum())} frames"
        )
        print(format_confusion(matrix, meta.classes))
        print(f"grasp accuracy (majority of frames) {np.mean(grasp_correct):.4f}")
        names = {"near_end": f"within {args.end_mm:g} mm of an end", "body": "the rest"}
        for name, r in by_region.items():
            print(f"  {names[name]}: {r['grasp_accuracy']:.4f} of {r['grasps']} grasps")
        for g, t, pr, e in wrong:
            where = "" if e is None else f", {e * 1000:.0f} mm from an end"
            print(f"  wrong: grasp {g} ({t}{where}) read as {pr}")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    manifest = read_manifest(args.dataset)
    print(f"{args.dataset}: {len(manifest['grasps'])} grasps, image {manifest['image_shape']}")
    for name, counts in manifest["counts_per_class"].items():
        print(f"  {name:<16} {counts['grasps']:>5} grasps {counts['frames']:>7} frames")
    print(f"  seeds {json.dumps(manifest.get('seeds', {}))}")
    noise = [g.get("params", {}).get("sensor_noise_seed") for g in manifest["grasps"]]
    recorded = sorted({json.dumps(seed) for seed in noise if seed is not None})
    print(f"  sensor noise seeds of the grasps: {', '.join(recorded) or 'none recorded'}")
    return 0


def _cmd_average(args: argparse.Namespace) -> int:
    models = [load_checkpoint(path) for path in args.model]
    model = average(models, args.weights)
    record = {
        "command": "python -m perception.classify " + shlex.join(args.argv),
        "weights": args.weights or [1.0] * len(models),
        # Each model's own record (a fine-tune's nests its start's, ``init``).
        "averaged": [
            {"path": path, "sha256": _sha256(Path(path)), "training": dict(meta.training)}
            for path, (_, meta) in zip(args.model, models, strict=True)
        ],
    }
    last = models[-1][1]
    meta = ModelMeta.for_spec(last.spec, last.classes, last.width, record)
    save_checkpoint(args.out, model, meta, half=not args.full_precision)
    print(f"saved {args.out}: the mean of {len(models)} models' weights")
    return 0


def parser() -> argparse.ArgumentParser:
    """The argument parser (public so docs and tests can list the options)."""
    top = argparse.ArgumentParser(
        prog="python -m perception.classify", description=__doc__.split("\n")[0]
    )
    sub = top.add_subparsers(dest="command", required=True)
    p = sub.add_parser("train", help="train a model on one or more datasets")
    p.add_argument("dataset", nargs="+")
    p.add_argument("--epochs", type=int, required=True)
    p.add_argument("--out", required=True, help="checkpoint path (.pt)")
    p.add_argument("--modality", choices=MODALITIES, default="depth")
    p.add_argument("--input-px", type=int, default=112)
    p.add_argument("--width", type=float, default=0.5, help="channel multiplier (1 = ResNet18)")
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--lr", type=float, default=0.05)
    p.add_argument("--momentum", type=float, default=0.9)
    p.add_argument("--weight-decay", type=float, default=5e-4)
    p.add_argument("--val-fraction", type=float, default=0.3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shift-px", type=int, default=4)
    p.add_argument("--max-frames-per-grasp", type=int, default=None)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    p.add_argument("--log", default=None, help="JSON lines, one per epoch")
    p.add_argument("--no-mean", action="store_true", help="do not subtract the mean image")
    p.add_argument(
        "--no-swap-sides", action="store_true", help="do not swap the bubbles (augmentation)"
    )
    p.add_argument("--full-precision", action="store_true", help="store float32 weights")
    p.add_argument(
        "--init", default=None, help="start from this checkpoint's weights (fine-tuning)"
    )
    p.add_argument(
        "--free-bubble",
        default=None,
        help="each bubble's no-contact frames (.npz of python -m sim.free_bubble): scale "
        "each imprint against them (with --imprint-depth-mm and --imprint-ir), or vary "
        "the dents about them (--dent-scale-min, --ir-change-scale-min)",
    )
    p.add_argument(
        "--imprint-depth-mm", type=float, default=None, help="the depth each dent is scaled to"
    )
    p.add_argument(
        "--imprint-ir", type=float, default=None, help="the IR change each imprint is scaled to"
    )
    p.add_argument(
        "--dent-scale-min",
        type=float,
        default=1.0,
        help="augmentation: each dent scaled about the free bubble (--free-bubble) by a "
        "factor drawn from [this, 1]",
    )
    p.add_argument(
        "--ir-change-scale-min",
        type=float,
        default=1.0,
        help="augmentation: each IR change scaled about the free bubble by a factor drawn "
        "from [this, 1]",
    )
    p.add_argument(
        "--ir-blur-px",
        type=float,
        default=0.0,
        help="augmentation: the IR blurred by a Gaussian of sigma drawn from [0, this] "
        "input pixels",
    )
    p.set_defaults(func=_cmd_train)
    e = sub.add_parser("evaluate", help="score a model on a held-out dataset")
    e.add_argument("model")
    e.add_argument("dataset")
    e.add_argument("--max-frames-per-grasp", type=int, default=None)
    e.add_argument("--threads", type=int, default=0)
    e.add_argument("--json", action="store_true")
    e.add_argument(
        "--end-mm",
        type=float,
        default=15.0,
        help="grasps this near an object's end are scored apart",
    )
    e.set_defaults(func=_cmd_evaluate)
    i = sub.add_parser("info", help="summarise a dataset's manifest")
    i.add_argument("dataset")
    i.set_defaults(func=_cmd_info)
    a = sub.add_parser("average", help="average the weights of a model and its fine-tunes")
    a.add_argument("model", nargs="+", help="checkpoints of one shape (a start, its fine-tunes)")
    a.add_argument("--weights", type=float, nargs="+", default=None, help="default: uniform")
    a.add_argument("--out", required=True, help="checkpoint path (.pt)")
    a.add_argument("--full-precision", action="store_true", help="store float32 weights")
    a.set_defaults(func=_cmd_average)
    return top


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser().parse_args(argv)
    args.argv = argv
    if getattr(args, "threads", 0) and args.command == "train":
        torch.set_num_threads(args.threads)
    try:
        return int(args.func(args))
    except ValueError as err:  # dataset, checkpoint and config errors name the culprit
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
