"""The tactile dataset on disk: one ``.npz`` per grasp and a JSON manifest.

Layout of a dataset directory::

    manifest.json
    grasps/grasp_000000.npz     # one file per grasp, written once, atomically
    grasps/grasp_000001.npz
    ...

Each grasp file holds the frames kept while that grasp was stable (``N`` frames):
``depth_left_m`` and ``depth_right_m`` float16 ``(N, H, W)`` metres with NaN invalid
(float16 keeps 0.06 mm steps at 10 cm, far below the ToF noise, and halves the size),
``ir_left`` and ``ir_right`` uint16 ``(N, H, W)``, ``stamp_nanos`` int64 ``(N,)``. Files are
read with ``np.load(..., allow_pickle=False)``: no pickle anywhere.

``manifest.json`` says what the dataset is::

    {"format": "softbubble-tactile-dataset", "version": 1,
     "classes": ["mug", ...], "image_shape": [H, W],
     "seeds": {...}, "scene": {...},            # how it was generated
     "counts_per_class": {"mug": {"grasps": 12, "frames": 240}, ...},
     "grasps": [{"grasp_id": 0, "object_class": "mug", "frames": 20,
                 "file": "grasps/grasp_000000.npz", "params": {...}}, ...]}

A grasp is in the manifest only once its file is complete, so a run that stops midway
resumes from the manifest: the grasps it lists are done, any other is done again.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from perception.classify.preprocess import InputSpec, frame_input

FORMAT = "softbubble-tactile-dataset"
VERSION = 1
MANIFEST = "manifest.json"
ARRAYS = ("depth_left_m", "depth_right_m", "ir_left", "ir_right", "stamp_nanos")


class DatasetError(ValueError):
    """A dataset directory or manifest is missing, malformed or inconsistent."""


def _write_atomically(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def read_manifest(root: str | Path) -> dict[str, Any]:
    """The manifest of a dataset directory, checked for format and version.

    Raises:
        DatasetError: no manifest, or not a dataset of this format and version.
    """
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise DatasetError(f"{root}: no {MANIFEST}; not a tactile dataset")
    manifest: dict[str, Any] = json.loads(path.read_text())
    if manifest.get("format") != FORMAT or manifest.get("version") != VERSION:
        raise DatasetError(
            f"{path}: format/version must be {FORMAT!r}/{VERSION}, "
            f"got {manifest.get('format')!r}/{manifest.get('version')!r}"
        )
    for key in ("classes", "grasps", "image_shape"):
        if key not in manifest:
            raise DatasetError(f"{path}: missing key {key!r}")
    return manifest


def counts_per_class(
    classes: Sequence[str], grasps: Sequence[Mapping[str, Any]]
) -> dict[str, dict[str, int]]:
    """``{class: {"grasps": g, "frames": f}}`` over the grasp entries of a manifest."""
    counts = {name: {"grasps": 0, "frames": 0} for name in classes}
    for entry in grasps:
        counts[entry["object_class"]]["grasps"] += 1
        counts[entry["object_class"]]["frames"] += int(entry["frames"])
    return counts


@dataclass
class GraspBuffer:
    """The frames of one grasp being recorded, before they are written."""

    depth_left_m: list[np.ndarray] = field(default_factory=list)
    depth_right_m: list[np.ndarray] = field(default_factory=list)
    ir_left: list[np.ndarray] = field(default_factory=list)
    ir_right: list[np.ndarray] = field(default_factory=list)
    stamp_nanos: list[int] = field(default_factory=list)

    def add(
        self,
        depth_left_m: np.ndarray,
        depth_right_m: np.ndarray,
        ir_left: np.ndarray,
        ir_right: np.ndarray,
        stamp_nanos: int,
    ) -> None:
        """Append one frame pair (copied, in the on-disk dtypes)."""
        self.depth_left_m.append(np.asarray(depth_left_m, dtype=np.float16))
        self.depth_right_m.append(np.asarray(depth_right_m, dtype=np.float16))
        self.ir_left.append(np.asarray(ir_left, dtype=np.uint16).copy())
        self.ir_right.append(np.asarray(ir_right, dtype=np.uint16).copy())
        self.stamp_nanos.append(int(stamp_nanos))

    def __len__(self) -> int:
        return len(self.stamp_nanos)

    def arrays(self) -> dict[str, np.ndarray]:
        """The stacked arrays, keyed as in the grasp file."""
        return {
            "depth_left_m": np.stack(self.depth_left_m),
            "depth_right_m": np.stack(self.depth_right_m),
            "ir_left": np.stack(self.ir_left),
            "ir_right": np.stack(self.ir_right),
            "stamp_nanos": np.asarray(self.stamp_nanos, dtype=np.int64),
        }


class DatasetWriter:
    """Writes grasps into a dataset directory and keeps its manifest current.

    Args:
        root: the dataset directory (created if missing).
        classes: every class the dataset may hold, in label order.
        seeds: how the grasps were drawn (saved in the manifest; a resume must match).
        scene: scene parameters (saved in the manifest; a resume must match).
        resume: continue a dataset that exists; if False, an existing one is an error.

    Raises:
        DatasetError: the directory holds a dataset and ``resume`` is False, or it holds
            one with other classes, seeds or scene parameters.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        classes: Sequence[str],
        seeds: Mapping[str, Any],
        scene: Mapping[str, Any],
        resume: bool = True,
    ) -> None:
        self.root = Path(root)
        if len(set(classes)) != len(classes) or len(classes) < 2:
            raise DatasetError(f"classes must be >= 2 distinct names, got {list(classes)}")
        wanted = {
            "classes": list(classes),
            "seeds": json.loads(json.dumps(dict(seeds))),
            "scene": json.loads(json.dumps(dict(scene))),
        }
        if (self.root / MANIFEST).exists():
            if not resume:
                raise DatasetError(f"{self.root}: a dataset exists here and resume is off")
            self.manifest = read_manifest(self.root)
            for key, value in wanted.items():
                if self.manifest.get(key) != value:
                    raise DatasetError(
                        f"{self.root}: cannot resume, manifest {key} is "
                        f"{self.manifest.get(key)!r}, this run has {value!r}"
                    )
        else:
            self.manifest = {
                "format": FORMAT,
                "version": VERSION,
                **wanted,
                "image_shape": None,
                "counts_per_class": counts_per_class(classes, []),
                "grasps": [],
            }
        (self.root / "grasps").mkdir(parents=True, exist_ok=True)
        self._save_manifest()

    @property
    def classes(self) -> list[str]:
        return list(self.manifest["classes"])

    def done_grasp_ids(self) -> set[int]:
        """Grasp ids already written (a resumed run skips them)."""
        return {int(entry["grasp_id"]) for entry in self.manifest["grasps"]}

    def write_grasp(
        self,
        grasp_id: int,
        object_class: str,
        buffer: GraspBuffer,
        params: Mapping[str, Any] | None = None,
    ) -> Path:
        """Write one grasp's frames and add it to the manifest; returns the file.

        Raises:
            DatasetError: unknown class, no frames, a grasp id written before, or images
                of another shape than the dataset's.
        """
        if object_class not in self.manifest["classes"]:
            raise DatasetError(
                f"object_class {object_class!r} is not one of {self.manifest['classes']}"
            )
        if len(buffer) == 0:
            raise DatasetError(f"grasp {grasp_id}: no frames to write")
        if grasp_id in self.done_grasp_ids():
            raise DatasetError(f"grasp {grasp_id} is already in {self.root}")
        arrays = buffer.arrays()
        shape = list(arrays["depth_left_m"].shape[1:])
        if self.manifest["image_shape"] is None:
            self.manifest["image_shape"] = shape
        elif self.manifest["image_shape"] != shape:
            raise DatasetError(
                f"grasp {grasp_id}: image shape {shape}, dataset has {self.manifest['image_shape']}"
            )
        relative = f"grasps/grasp_{grasp_id:06d}.npz"
        path = self.root / relative
        tmp = path.with_name(path.stem + ".tmp.npz")
        # numpy's stub types ** as possibly its allow_pickle flag; these are array names.
        np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
        self.manifest["grasps"].append(
            {
                "grasp_id": int(grasp_id),
                "object_class": object_class,
                "frames": len(buffer),
                "file": relative,
                "params": json.loads(json.dumps(dict(params or {}))),
            }
        )
        self.manifest["grasps"].sort(key=lambda entry: entry["grasp_id"])
        self._save_manifest()
        return path

    def _save_manifest(self) -> None:
        self.manifest["counts_per_class"] = counts_per_class(
            self.manifest["classes"], self.manifest["grasps"]
        )
        text = json.dumps(self.manifest, indent=1, sort_keys=False)
        _write_atomically(self.root / MANIFEST, text.encode())


def read_grasp(root: str | Path, entry: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The arrays of one grasp entry of the manifest (no pickle).

    Raises:
        DatasetError: the file lacks an array or its frame count differs from the entry.
    """
    path = Path(root) / entry["file"]
    with np.load(path, allow_pickle=False) as data:
        missing = [name for name in ARRAYS if name not in data.files]
        if missing:
            raise DatasetError(f"{path}: missing arrays {missing}")
        arrays = {name: data[name] for name in ARRAYS}
    if len(arrays["stamp_nanos"]) != entry["frames"]:
        raise DatasetError(
            f"{path}: {len(arrays['stamp_nanos'])} frames, manifest says {entry['frames']}"
        )
    return arrays


def iter_grasps(root: str | Path) -> Iterator[tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """``(entry, arrays)`` for every grasp of the dataset, in grasp id order."""
    manifest = read_manifest(root)
    for entry in manifest["grasps"]:
        yield entry, read_grasp(root, entry)


@dataclass(frozen=True)
class Samples:
    """Network inputs of a dataset: ``x`` float16 ``(N, C, px, px)``, labels, grasp ids."""

    x: np.ndarray
    labels: np.ndarray
    grasp_ids: np.ndarray
    classes: list[str]


def load_samples(
    root: str | Path,
    spec: InputSpec,
    *,
    classes: Sequence[str] | None = None,
    max_frames_per_grasp: int | None = None,
    max_grasps: int | None = None,
) -> Samples:
    """Every frame of a dataset turned into network inputs.

    Args:
        root: the dataset directory.
        spec: modality and input size.
        classes: label order to use (a model's classes); default the manifest's. Every
            class the dataset holds frames of must be in it.
        max_frames_per_grasp: keep at most this many frames of each grasp, evenly spread
            (frames of one grasp are nearly alike; fewer of them cost less to train on).
        max_grasps: use only the first this many grasps of the manifest (smaller runs).

    Raises:
        DatasetError: the dataset holds a class not in ``classes``, or holds no frames.
    """
    manifest = read_manifest(root)
    classes = list(classes if classes is not None else manifest["classes"])
    index = {name: i for i, name in enumerate(classes)}
    xs, labels, grasp_ids = [], [], []
    for count, (entry, arrays) in enumerate(iter_grasps(root)):
        if max_grasps is not None and count >= max_grasps:
            break
        if entry["object_class"] not in index:
            raise DatasetError(
                f"{root}: grasp {entry['grasp_id']} is a {entry['object_class']!r}, "
                f"not one of the classes {classes}"
            )
        frames = np.arange(entry["frames"])
        if max_frames_per_grasp is not None and len(frames) > max_frames_per_grasp:
            frames = np.linspace(0, len(frames) - 1, max_frames_per_grasp).round().astype(int)
        for i in frames:
            xs.append(
                frame_input(
                    spec,
                    depth_left_m=arrays["depth_left_m"][i],
                    depth_right_m=arrays["depth_right_m"][i],
                    ir_left=arrays["ir_left"][i],
                    ir_right=arrays["ir_right"][i],
                ).astype(np.float16)
            )
            labels.append(index[entry["object_class"]])
            grasp_ids.append(int(entry["grasp_id"]))
    if not xs:
        raise DatasetError(f"{root}: the dataset holds no frames")
    return Samples(
        x=np.stack(xs),
        labels=np.asarray(labels, dtype=np.int64),
        grasp_ids=np.asarray(grasp_ids, dtype=np.int64),
        classes=classes,
    )


def concat_samples(parts: Sequence[Samples]) -> Samples:
    """Several datasets' samples as one; grasp ids renumbered so no two datasets share one.

    Raises:
        DatasetError: no parts, or parts labelled with different classes.
    """
    if not parts:
        raise DatasetError("no datasets to join")
    classes = parts[0].classes
    grasp_ids = []
    offset = 0
    for part in parts:
        if part.classes != classes:
            raise DatasetError(f"datasets label different classes: {classes} and {part.classes}")
        grasp_ids.append(part.grasp_ids - part.grasp_ids.min() + offset)
        offset = int(grasp_ids[-1].max()) + 1
    return Samples(
        x=np.concatenate([p.x for p in parts]),
        labels=np.concatenate([p.labels for p in parts]),
        grasp_ids=np.concatenate(grasp_ids),
        classes=classes,
    )


def merge_datasets(parts: Sequence[str | Path], out: str | Path) -> dict[str, Any]:
    """One dataset made of several (the worlds of a batch run), in the order given.

    Grasps are numbered anew from 0, part after part, each part's in its grasp-id order;
    each entry says where it came from (``source``: the part's index and seeds, and its
    grasp id there). Files are hard-linked where the file system allows, else copied.
    The result depends only on the parts and their order, not on how or where they
    were made. Returns the new manifest.

    Raises:
        DatasetError: no parts, parts of other classes or image shapes, or ``out``
            already holds a dataset.
    """
    root = Path(out)
    if (root / MANIFEST).exists():
        raise DatasetError(f"{root}: a dataset exists here; merge into a new folder")
    manifests = [read_manifest(part) for part in parts]
    if not manifests:
        raise DatasetError("merge: no datasets given")
    first = manifests[0]
    for part, manifest in zip(parts, manifests, strict=True):
        for key in ("classes", "image_shape"):
            if manifest[key] != first[key] and manifest["grasps"]:
                raise DatasetError(
                    f"{part}: {key} {manifest[key]!r}, {parts[0]} has {first[key]!r}"
                )
    (root / "grasps").mkdir(parents=True, exist_ok=True)
    grasps: list[dict[str, Any]] = []
    for index, (part, manifest) in enumerate(zip(parts, manifests, strict=True)):
        for entry in sorted(manifest["grasps"], key=lambda e: int(e["grasp_id"])):
            relative = f"grasps/grasp_{len(grasps):06d}.npz"
            target = root / relative
            target.unlink(missing_ok=True)
            try:
                os.link(Path(part) / entry["file"], target)
            except OSError:
                target.write_bytes((Path(part) / entry["file"]).read_bytes())
            source = {"part": index, "seeds": manifest["seeds"], "grasp_id": entry["grasp_id"]}
            grasps.append({**entry, "grasp_id": len(grasps), "file": relative, "source": source})
    merged = {
        "format": FORMAT,
        "version": VERSION,
        "classes": first["classes"],
        "seeds": {"parts": [m["seeds"] for m in manifests]},
        "scene": {"parts": [m["scene"] for m in manifests]},
        "image_shape": first["image_shape"],
        "counts_per_class": counts_per_class(first["classes"], grasps),
        "grasps": grasps,
    }
    _write_atomically(root / MANIFEST, json.dumps(merged, indent=1).encode())
    return merged
