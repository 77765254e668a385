"""A tiny training run learns; checkpoints round-trip with weights_only; the CLI works."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from perception.classify.__main__ import main
from perception.classify.autolabel import end_distance_m
from perception.classify.checkpoint import (
    CheckpointError,
    Classifier,
    ModelMeta,
    average,
    build_model,
    load_checkpoint,
    save_checkpoint,
)
from perception.classify.dataset import load_samples
from perception.classify.preprocess import DEPTH_CENTER_M, INVALID_DEPTH_M, InputSpec
from perception.classify.synthetic import toy_frame, write_toy_dataset
from perception.classify.train import TrainConfig, confusion_matrix, format_confusion, train

TINY = {"input_px": 32, "width": 0.125, "batch_size": 16, "lr": 0.05}


@pytest.fixture(scope="module")
def toy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_toy_dataset(
        tmp_path_factory.mktemp("toy") / "data", grasps_per_class=8, frames_per_grasp=4, seed=0
    )


@pytest.fixture(scope="module")
def trained(toy: Path):
    torch.set_num_threads(1)
    config = TrainConfig(epochs=20, modality="depth", seed=0, **TINY)
    samples = load_samples(toy, InputSpec(modality="depth", input_px=32))
    return train(samples, config, progress_stream=io.StringIO())


def test_tiny_run_learns(trained) -> None:
    history = trained.history
    assert len(history) == 20
    assert history[-1]["train_loss"] < 0.6 * history[0]["train_loss"]
    assert history[-1]["train_accuracy"] > 0.6  # chance is 0.25
    assert history[-1]["val_accuracy"] > 0.5
    # The confusion matrix covers the validation frames: 30% of 8 grasps = 2 per class.
    assert trained.confusion.shape == (4, 4)
    assert trained.confusion.sum() == 4 * 2 * 4
    assert not set(trained.split["train_grasps"]) & set(trained.split["val_grasps"])


def test_checkpoint_round_trip_weights_only(trained, tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_checkpoint(path, trained.model, trained.meta, half=True)
    # The file is plain data: torch's safe loader reads it.
    payload = torch.load(path, weights_only=True)
    assert payload["classes"] == ["mug", "pet_bottle", "square_bottle", "wine_glass"]
    assert payload["modality"] == "depth" and payload["input_px"] == 32
    assert payload["width"] == 0.125
    assert payload["state_dict"]["fc.weight"].dtype == torch.float16
    model, meta = load_checkpoint(path)
    assert meta.classes == trained.meta.classes and meta.width == 0.125
    assert meta.training["config"]["epochs"] == 20
    x = torch.randn(2, 1, 32, 32)
    with torch.inference_mode():
        want = torch.softmax(trained.model.eval()(x), 1)
        got = torch.softmax(model(x), 1)
    assert torch.allclose(want, got, atol=2e-2)  # float16 weights
    full = tmp_path / "full.pt"
    save_checkpoint(full, trained.model, trained.meta, half=False)
    with torch.inference_mode():
        assert torch.allclose(want, torch.softmax(load_checkpoint(full)[0](x), 1), atol=1e-6)


def test_classifier_on_frames(trained) -> None:
    classifier = Classifier(trained.model, trained.meta)
    rng = np.random.default_rng(5)
    left, left_ir = toy_frame("bar", (24, 32), rng)
    right, right_ir = toy_frame("bar", (24, 32), rng)
    probs = classifier.classify(depth_left_m=left, depth_right_m=right)
    assert probs.shape == (4,) and probs.dtype == np.float32
    assert abs(float(probs.sum()) - 1) < 1e-5


def test_bad_checkpoints_are_refused(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="no such"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a softbubble-classifier"):
        load_checkpoint(tmp_path / "other.pt")
    # A pickled object (not plain data) is refused by the weights-only loader.
    torch.save({"format": "softbubble-classifier", "x": Path("/")}, tmp_path / "obj.pt")
    with pytest.raises(CheckpointError, match="weights-only"):
        load_checkpoint(tmp_path / "obj.pt")
    meta = ModelMeta.for_spec(InputSpec(modality="ir", input_px=32), ["a", "b"], 0.125)
    save_checkpoint(tmp_path / "m.pt", build_model(meta), meta, half=True)
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    payload["width"] = 0.25  # weights of another shape than the meta says
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match="do not fit"):
        load_checkpoint(tmp_path / "bad.pt")


def test_a_checkpoint_without_invalid_depth_reads_holes_as_the_centre(
    trained, toy: Path, tmp_path: Path
) -> None:
    # Checkpoints saved before the invalid depth was stored were trained with holes at
    # the centre: they load that way, and a fine-tune of one may take the new reading.
    save_checkpoint(tmp_path / "new.pt", trained.model, trained.meta, half=True)
    assert load_checkpoint(tmp_path / "new.pt")[1].invalid_depth_m == INVALID_DEPTH_M
    payload = torch.load(tmp_path / "new.pt", weights_only=True)
    del payload["invalid_depth_m"]
    torch.save(payload, tmp_path / "old.pt")
    old = Classifier.load(tmp_path / "old.pt")
    assert old.spec.invalid_depth_m == DEPTH_CENTER_M
    hole = np.full((24, 32), np.nan, np.float32)
    flat = np.full((24, 32), DEPTH_CENTER_M, np.float32)
    assert np.allclose(
        old.classify(depth_left_m=hole, depth_right_m=hole),
        old.classify(depth_left_m=flat, depth_right_m=flat),
    )
    samples = load_samples(toy, InputSpec(modality="depth", input_px=32))
    config = TrainConfig(epochs=1, modality="depth", seed=1, **TINY)
    tuned = train(samples, config, progress_stream=io.StringIO(), init=(old.model, old.meta))
    assert tuned.meta.invalid_depth_m == INVALID_DEPTH_M
    # Models that read holes differently are not one model's fine-tunes: no average.
    with pytest.raises(CheckpointError, match="invalid_depth_m"):
        average([(old.model, old.meta), (tuned.model, tuned.meta)])


def test_fine_tuning_starts_from_the_init_model(
    trained, toy: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    samples = load_samples(toy, InputSpec(modality="depth", input_px=32))
    config = TrainConfig(epochs=1, modality="depth", seed=1, **TINY)
    start = {k: v.clone() for k, v in trained.model.state_dict().items()}
    tuned = train(
        samples, config, progress_stream=io.StringIO(), init=(trained.model, trained.meta)
    )
    # It begins where the trained model ended: one epoch keeps it far ahead of a fresh start.
    fresh = train(samples, config, progress_stream=io.StringIO())
    assert tuned.history[0]["train_loss"] < 0.8 * fresh.history[0]["train_loss"]
    assert torch.equal(tuned.model.input_mean, start["input_mean"])  # its mean image kept
    after = trained.model.state_dict()
    assert all(torch.equal(after[k], v) for k, v in start.items())  # the start untouched
    # A model of other inputs or classes is refused, naming what differs.
    other = ModelMeta.for_spec(InputSpec(modality="ir", input_px=32), trained.meta.classes, 0.125)
    with pytest.raises(ValueError, match="init model has modality 'ir'"):
        train(samples, config, progress_stream=io.StringIO(), init=(build_model(other), other))
    # The CLI records where it started.
    base = tmp_path / "base.pt"
    save_checkpoint(base, trained.model, trained.meta, half=True)
    out = tmp_path / "tuned.pt"
    args = ["train", str(toy), "--epochs", "1", "--out", str(out), "--init", str(base)]
    assert main([*args, "--input-px", "32", "--width", "0.125", "--threads", "1"]) == 0
    record = load_checkpoint(out)[1].training
    assert record["init"]["path"] == str(base) and len(record["init"]["sha256"]) == 64
    assert record["init"]["training"]["config"]["epochs"] == 20
    capsys.readouterr()
    # Another width is refused before any dataset loads, naming the field.
    assert main([*args, "--input-px", "32", "--width", "0.25"]) == 2
    printed = capsys.readouterr()
    assert "init model has width 0.125, the training needs 0.25" in printed.err
    assert "frames loaded" not in printed.out


def test_average_of_a_model_and_its_fine_tune(
    trained, toy: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    samples = load_samples(toy, InputSpec(modality="depth", input_px=32))
    config = TrainConfig(epochs=2, modality="depth", seed=1, **TINY)
    tuned = train(
        samples, config, progress_stream=io.StringIO(), init=(trained.model, trained.meta)
    )
    pair = [(trained.model, trained.meta), (tuned.model, tuned.meta)]
    start, end = trained.model.state_dict(), tuned.model.state_dict()
    assert not torch.equal(start["fc.weight"], end["fc.weight"])
    # Weights (1, 0) and (0, 1) give the two models; (3, 1) the mix, tensor by tensor (the
    # batch-norm counters are the last model's).
    for weights, want in (([1, 0], start), ([0, 1], end)):
        got = average(pair, weights).state_dict()
        assert all(torch.equal(got[k], v) for k, v in want.items() if v.is_floating_point())
    mix = average(pair, [3, 1]).state_dict()
    for name, tensor in mix.items():
        if tensor.is_floating_point():
            assert torch.allclose(tensor, 0.75 * start[name] + 0.25 * end[name])
    assert all(
        torch.allclose(average(pair).state_dict()[k], 0.5 * (start[k] + end[k]))
        for k in ["fc.weight", "input_mean"]
    )
    for weights, message in (([1], "1 weights for 2 models"), ([1, -1], "must be >= 0")):
        with pytest.raises(CheckpointError, match=message):
            average(pair, weights)
    other = ModelMeta.for_spec(InputSpec(modality="ir", input_px=32), trained.meta.classes, 0.125)
    with pytest.raises(CheckpointError, match="differ in modality"):
        average([pair[0], (build_model(other), other)])
    # The CLI writes a checkpoint that records every model and the weights.
    paths = [tmp_path / "start.pt", tmp_path / "tuned.pt", tmp_path / "mix.pt"]
    save_checkpoint(paths[0], trained.model, trained.meta, half=False)
    save_checkpoint(paths[1], tuned.model, tuned.meta, half=False)
    argv = ["average", str(paths[0]), str(paths[1]), "--out", str(paths[2])]
    assert main([*argv, "--weights", "3", "1", "--full-precision"]) == 0
    model, meta = load_checkpoint(paths[2])
    assert meta.training["weights"] == [3.0, 1.0]
    assert [m["path"] for m in meta.training["averaged"]] == [str(p) for p in paths[:2]]
    assert meta.training["averaged"][1]["training"]["config"]["epochs"] == 2
    assert all(torch.allclose(model.state_dict()[k], v) for k, v in mix.items())
    assert main([*argv, "--weights", "1"]) == 2
    assert "1 weights for 2 models" in capsys.readouterr().err


def test_confusion_matrix() -> None:
    matrix = confusion_matrix(np.array([0, 0, 1, 2]), np.array([0, 1, 1, 2]), 3)
    assert matrix.tolist() == [[1, 1, 0], [0, 1, 0], [0, 0, 1]]
    assert "accuracy 0.7500 (3/4)" in format_confusion(matrix, ["a", "b", "c"])


def test_cli_train_and_evaluate(toy: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "cli.pt"
    # Two datasets train as one (here the same one twice: its grasps counted apart).
    args = ["train", str(toy), str(toy), "--epochs", "2", "--out", str(out), "--modality", "both"]
    args += ["--input-px", "32", "--width", "0.125", "--batch-size", "16", "--threads", "1"]
    assert main(args) == 0
    printed = capsys.readouterr()
    assert "epoch 2:" in printed.out and "val loss" in printed.out
    assert "validation confusion matrix" in printed.out
    assert "epoch 1/2 [" in printed.err  # the progress bar
    log = [json.loads(line) for line in Path(str(out) + ".log.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in log] == [1, 2]
    meta = load_checkpoint(out)[1]
    assert meta.modality == "both"
    assert meta.training["command"].startswith("python -m perception.classify train")
    assert [d["path"] for d in meta.training["datasets"]] == [str(toy)] * 2
    assert f"{2 * 4 * 8 * 4} frames loaded" in printed.out
    assert len(meta.training["datasets"][0]["manifest_sha256"]) == 64
    assert main(["evaluate", str(out), str(toy), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 4 * 8 * 4
    assert np.asarray(result["confusion"]).sum() == result["frames"]
    assert 0 <= result["accuracy"] <= 1
    assert len(result["wrong_grasps"]) == round(32 * (1 - result["grasp_accuracy"]))
    assert result["by_region"] == {}  # toy grasps say nothing of where they were held
    # Auto-labelled grasps record the object and height: scored near an end and on the body.
    labelled = tmp_path / "labelled"
    shutil.copytree(toy, labelled)
    manifest = json.loads((labelled / "manifest.json").read_text())
    rim = end_distance_m("mug", 0.0)  # the mug's half length: its rim, from its middle
    for entry in manifest["grasps"]:  # every other grasp 10 mm below the rim, the rest 20
        entry["params"] = {
            "object_name": "mug",
            "height_m": rim - 0.01 * (1 + entry["grasp_id"] % 2),
            "sensor_noise_seed": 21,
        }
    (labelled / "manifest.json").write_text(json.dumps(manifest))
    assert main(["info", str(toy)]) == 0
    assert "sensor noise seeds of the grasps: none recorded" in capsys.readouterr().out
    assert main(["info", str(labelled)]) == 0
    info = capsys.readouterr().out
    assert "32 grasps" in info and "sensor noise seeds of the grasps: 21" in info
    assert main(["evaluate", str(out), str(labelled), "--json", "--end-mm", "15"]) == 0
    regions = json.loads(capsys.readouterr().out)["by_region"]
    assert regions["near_end"]["grasps"] == regions["body"]["grasps"] == 16
    assert main(["evaluate", str(out), str(labelled)]) == 0
    assert "within 15 mm of an end:" in capsys.readouterr().out
    assert main(["evaluate", str(out), str(labelled), "--end-mm", "0"]) == 2
    assert "--end-mm must be > 0" in capsys.readouterr().err
    # Errors are one line naming the culprit, exit status 2.
    assert main(["evaluate", str(out), str(tmp_path)]) == 2
    assert "no manifest.json" in capsys.readouterr().err


def test_side_swap_exchanges_the_bubble_halves_of_about_half_the_batch() -> None:
    from perception.classify.train import _sides_swapped

    batch = torch.arange(64 * 2 * 4 * 6, dtype=torch.float32).reshape(64, 2, 4, 6)
    out = _sides_swapped(batch, np.random.default_rng(0))
    swapped = [not torch.equal(out[i], batch[i]) for i in range(len(batch))]
    assert 16 < sum(swapped) < 48
    for i, was in enumerate(swapped):
        if was:
            assert torch.equal(out[i, :, :, :3], batch[i, :, :, 3:])
            assert torch.equal(out[i, :, :, 3:], batch[i, :, :, :3])
    with pytest.raises(ValueError, match="even input_px"):
        TrainConfig(epochs=1, input_px=33)


def test_cli_trains_with_the_imprint_scale(toy: Path, tmp_path: Path, capsys) -> None:
    # --free-bubble and the two sizes train a model on scaled imprints; the checkpoint
    # carries them, and evaluate reads frames as the model was trained.
    h, w = json.loads((toy / "manifest.json").read_text())["image_shape"]
    free = np.full((h, w), 0.06, np.float32)
    np.savez(
        tmp_path / "free.npz",
        depth_left_m=free,
        depth_right_m=free,
        ir_left=np.full((h, w), 4000, np.float32),
        ir_right=np.full((h, w), 4000, np.float32),
    )
    out = tmp_path / "imprint.pt"
    args = ["train", str(toy), "--epochs", "1", "--out", str(out), "--modality", "both"]
    args += ["--input-px", "32", "--width", "0.125", "--batch-size", "16", "--threads", "1"]
    imprint = ["--free-bubble", str(tmp_path / "free.npz"), "--imprint-depth-mm", "25"]
    assert main([*args, *imprint, "--imprint-ir", "2500"]) == 0
    meta = load_checkpoint(out)[1]
    assert (meta.imprint_depth_m, meta.imprint_ir) == (0.025, 2500.0)
    assert meta.free is not None and np.allclose(meta.free.depth_left_m, 0.06, atol=1e-4)
    capsys.readouterr()
    assert main(["evaluate", str(out), str(toy), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 4 * 8 * 4
    assert main([*args, *imprint]) == 2  # one of the three missing
    assert "go together" in capsys.readouterr().err


def test_membrane_variation_scales_each_change_about_the_free_input() -> None:
    # Each input's dent (depth channel) and IR change, against the free bubble's input,
    # come out scaled by one factor per input and channel, drawn from the configured
    # range; the batch given is left as it was.
    from perception.classify.train import _membrane_varied

    rng = np.random.default_rng(1)
    batch = torch.from_numpy(rng.normal(size=(64, 2, 8, 10)).astype(np.float32))
    before = batch.clone()
    free = torch.from_numpy(rng.normal(size=(2, 8, 10)).astype(np.float32))
    config = TrainConfig(epochs=1, modality="both", dent_scale_min=0.5, ir_change_scale_min=0.3)
    out = _membrane_varied(batch, free, config, np.random.default_rng(2))
    assert torch.equal(batch, before)
    for channel, low in ((0, 0.5), (1, 0.3)):
        change, was = out[:, channel] - free[channel], batch[:, channel] - free[channel]
        scale = (change * was).sum(dim=(1, 2)) / (was * was).sum(dim=(1, 2))
        assert torch.allclose(change, scale[:, None, None] * was, atol=1e-5)
        assert low <= float(scale.min()) and float(scale.max()) <= 1
        assert float(scale.max() - scale.min()) > 0.5 * (1 - low)  # drawn, not one value
    # Off (the defaults): the same tensor back, and no number drawn.
    quiet = np.random.default_rng(3)
    assert _membrane_varied(batch, None, TrainConfig(epochs=1), quiet) is batch
    assert quiet.random() == np.random.default_rng(3).random()


def test_membrane_variation_blurs_each_bubble_on_its_own() -> None:
    # The IR channel blurred, each bubble's half apart: a point beside the seam spreads
    # within its half and not one value crosses into the other (blurred together, the
    # columns beyond the seam would take some of it); the depth channel is untouched.
    from perception.classify.train import _membrane_varied

    batch = torch.zeros(32, 2, 16, 16)
    batch[:, 1, :, :8], batch[:, 1, :, 8:] = 1.0, -1.0
    batch[:, 1, 8, 7] = 9.0
    batch[:, 0] = torch.from_numpy(np.random.default_rng(4).normal(size=(32, 16, 16)))
    config = TrainConfig(epochs=1, modality="both", ir_blur_px=2.0)
    out = _membrane_varied(batch, None, config, np.random.default_rng(5))
    assert torch.equal(out[:, 0], batch[:, 0])
    # A blurred constant is the constant to rounding; a share of the point would be > 1e-3.
    assert torch.allclose(out[:, 1, :, 8:], batch[:, 1, :, 8:], rtol=0, atol=1e-5)
    peaks, beside = out[:, 1, 8, 7], out[:, 1, 8, 6]
    assert float(peaks.max()) <= 9.0 and int((peaks < 5.0).sum()) > 16  # sigma up to 2
    assert int((beside > 1.5).sum()) > 16
    assert float(out[:, 1, :, :8].min()) >= 1.0 - 1e-5  # nothing from the other side


def test_membrane_variation_is_refused_where_it_cannot_act(toy: Path) -> None:
    for bad, message in (
        ({"dent_scale_min": 0.0}, "dent_scale_min must be in"),
        ({"ir_change_scale_min": 1.5}, "ir_change_scale_min must be in"),
        ({"ir_blur_px": -1.0}, "ir_blur_px must be >= 0"),
        ({"modality": "ir", "dent_scale_min": 0.5}, "modality 'ir' has none"),
        ({"modality": "depth", "ir_blur_px": 1.0}, "modality 'depth' has none"),
    ):
        with pytest.raises(ValueError, match=message):
            TrainConfig(epochs=1, **bad)
    config = TrainConfig(epochs=1, modality="depth", dent_scale_min=0.5, **TINY)
    samples = load_samples(toy, InputSpec(modality="depth", input_px=32))
    with pytest.raises(ValueError, match=r"free bubble's input of shape \(1, 32, 32\): got none"):
        train(samples, config, progress_stream=io.StringIO())
    with pytest.raises(ValueError, match=r"got shape \(2, 32, 32\)"):
        train(samples, config, progress_stream=io.StringIO(), free_input=np.zeros((2, 32, 32)))


def test_cli_trains_with_the_membrane_varied(toy: Path, tmp_path: Path, capsys) -> None:
    # --dent-scale-min, --ir-change-scale-min and --ir-blur-px train about --free-bubble's
    # frames; the checkpoint records them; each needs the other as the errors say.
    h, w = json.loads((toy / "manifest.json").read_text())["image_shape"]
    free = np.full((h, w), 0.06, np.float32)
    ir = np.full((h, w), 4000, np.float32)
    free_path = tmp_path / "free.npz"
    np.savez(free_path, depth_left_m=free, depth_right_m=free, ir_left=ir, ir_right=ir)
    out = tmp_path / "varied.pt"
    args = ["train", str(toy), "--epochs", "1", "--out", str(out), "--modality", "both"]
    args += ["--input-px", "32", "--width", "0.125", "--batch-size", "16", "--threads", "1"]
    varied = ["--dent-scale-min", "0.5", "--ir-change-scale-min", "0.4", "--ir-blur-px", "1"]
    assert main([*args, *varied, "--free-bubble", str(free_path)]) == 0
    config = load_checkpoint(out)[1].training["config"]
    assert (config["dent_scale_min"], config["ir_change_scale_min"], config["ir_blur_px"]) == (
        0.5,
        0.4,
        1.0,
    )
    capsys.readouterr()
    assert main([*args, *varied]) == 2
    assert "give --free-bubble" in capsys.readouterr().err
    assert main([*args, "--free-bubble", str(free_path)]) == 2
    assert "--free-bubble is for the imprint scale" in capsys.readouterr().err
    assert main([*args, "--ir-blur-px", "1"]) == 0  # a blur alone needs no free bubble
