"""The dataset format: writer, manifest, resume, loading without pickle, split by grasp."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from perception.classify.dataset import (
    DatasetError,
    DatasetWriter,
    GraspBuffer,
    concat_samples,
    load_samples,
    read_grasp,
    read_manifest,
)
from perception.classify.preprocess import InputSpec
from perception.classify.synthetic import write_toy_dataset
from perception.classify.train import split_by_grasp

CLASSES = ["mug", "pet_bottle"]


def _buffer(frames: int, shape: tuple[int, int] = (6, 8)) -> GraspBuffer:
    buffer = GraspBuffer()
    for i in range(frames):
        depth = np.full(shape, 0.08 + i * 1e-3, np.float32)
        depth[0, 0] = np.nan
        ir = np.full(shape, 1000 + i, np.uint16)
        buffer.add(depth, depth, ir, ir, stamp_nanos=i * 100)
    return buffer


def _writer(root: Path, **kwargs) -> DatasetWriter:
    args = {"classes": CLASSES, "seeds": {"autolabel": 3}, "scene": {"objects": CLASSES}}
    args.update(kwargs)
    return DatasetWriter(root, **args)


def test_manifest_counts_and_round_trip(tmp_path: Path) -> None:
    writer = _writer(tmp_path)
    writer.write_grasp(0, "mug", _buffer(3), {"height_m": 0.01})
    writer.write_grasp(1, "pet_bottle", _buffer(2))
    writer.write_grasp(2, "mug", _buffer(4))
    manifest = read_manifest(tmp_path)
    assert manifest["counts_per_class"] == {
        "mug": {"grasps": 2, "frames": 7},
        "pet_bottle": {"grasps": 1, "frames": 2},
    }
    assert manifest["seeds"] == {"autolabel": 3}
    assert manifest["image_shape"] == [6, 8]
    arrays = read_grasp(tmp_path, manifest["grasps"][0])
    assert arrays["depth_left_m"].dtype == np.float16
    assert arrays["ir_left"].dtype == np.uint16
    assert np.isnan(arrays["depth_left_m"][0, 0, 0])
    assert arrays["stamp_nanos"].tolist() == [0, 100, 200]
    assert manifest["grasps"][0]["params"] == {"height_m": 0.01}
    # Every array file loads without pickle.
    for entry in manifest["grasps"]:
        with np.load(tmp_path / entry["file"], allow_pickle=False) as data:
            assert all(data[name].dtype != object for name in data.files)


def test_resume_keeps_done_grasps_and_refuses_other_seeds(tmp_path: Path) -> None:
    _writer(tmp_path).write_grasp(0, "mug", _buffer(2))
    resumed = _writer(tmp_path)
    assert resumed.done_grasp_ids() == {0}
    resumed.write_grasp(1, "mug", _buffer(2))
    assert len(read_manifest(tmp_path)["grasps"]) == 2
    with pytest.raises(DatasetError, match="seeds"):
        _writer(tmp_path, seeds={"autolabel": 4})
    with pytest.raises(DatasetError, match="resume"):
        _writer(tmp_path, resume=False)


def test_writer_refuses_bad_grasps(tmp_path: Path) -> None:
    writer = _writer(tmp_path)
    with pytest.raises(DatasetError, match="wine_glass"):
        writer.write_grasp(0, "wine_glass", _buffer(1))
    with pytest.raises(DatasetError, match="no frames"):
        writer.write_grasp(0, "mug", GraspBuffer())
    writer.write_grasp(0, "mug", _buffer(1))
    with pytest.raises(DatasetError, match="already"):
        writer.write_grasp(0, "mug", _buffer(1))
    with pytest.raises(DatasetError, match="shape"):
        writer.write_grasp(1, "mug", _buffer(1, shape=(5, 8)))


def test_not_a_dataset(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(DatasetError, match="format"):
        read_manifest(tmp_path)


def test_load_samples_labels_and_subsampling(tmp_path: Path) -> None:
    write_toy_dataset(tmp_path, grasps_per_class=2, frames_per_grasp=5, seed=1)
    spec = InputSpec(modality="both", input_px=32)
    samples = load_samples(tmp_path, spec)
    assert samples.x.shape == (4 * 2 * 5, 2, 32, 32)
    assert samples.x.dtype == np.float16
    assert np.bincount(samples.labels).tolist() == [10, 10, 10, 10]
    fewer = load_samples(tmp_path, spec, max_frames_per_grasp=2)
    assert len(fewer.labels) == 16
    # A model's class order wins over the manifest's; a class it lacks is an error.
    reordered = load_samples(tmp_path, spec, classes=samples.classes[::-1])
    assert (reordered.labels == 3 - samples.labels).all()
    with pytest.raises(DatasetError, match="wine_glass"):
        load_samples(tmp_path, spec, classes=["mug", "pet_bottle", "square_bottle"])


def test_concat_samples_keeps_datasets_grasps_apart(tmp_path: Path) -> None:
    spec = InputSpec(modality="depth", input_px=32)
    write_toy_dataset(tmp_path / "a", grasps_per_class=2, frames_per_grasp=3, seed=1)
    write_toy_dataset(tmp_path / "b", grasps_per_class=1, frames_per_grasp=3, seed=2)
    a, b = load_samples(tmp_path / "a", spec), load_samples(tmp_path / "b", spec)
    both = concat_samples([a, b])
    assert len(both.labels) == len(a.labels) + len(b.labels) == 36
    # Both toy datasets number their grasps from 0: joined, they are 12 distinct grasps.
    assert set(a.grasp_ids) & set(b.grasp_ids)
    assert len(np.unique(both.grasp_ids)) == 12
    assert (both.x[: len(a.labels)] == a.x).all() and (
        both.labels[len(a.labels) :] == b.labels
    ).all()
    with pytest.raises(DatasetError, match="different classes"):
        concat_samples([a, load_samples(tmp_path / "b", spec, classes=a.classes[::-1])])
    with pytest.raises(DatasetError, match="no datasets"):
        concat_samples([])


def test_split_is_by_grasp_and_stratified() -> None:
    grasp_ids = np.repeat(np.arange(20), 7)
    labels = np.repeat(np.arange(20) % 4, 7)
    train_mask, val_mask = split_by_grasp(grasp_ids, labels, 0.3, seed=0)
    assert not (train_mask & val_mask).any() and (train_mask | val_mask).all()
    assert not set(grasp_ids[train_mask]) & set(grasp_ids[val_mask])
    # Five grasps per class, 30% -> 2 (rounded) per class in validation.
    assert np.bincount(labels[val_mask]).tolist() == [14, 14, 14, 14]
    again = split_by_grasp(grasp_ids, labels, 0.3, seed=0)[1]
    assert (again == val_mask).all()
