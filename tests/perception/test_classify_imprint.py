"""The imprint scale: each bubble's dent and IR change scaled to a canonical size against
its free frame, so an imprint's shape is kept and its depth dropped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from perception.classify.checkpoint import (
    CheckpointError,
    Classifier,
    ModelMeta,
    average,
    build_model,
    load_checkpoint,
    save_checkpoint,
)
from perception.classify.preprocess import (
    IMPRINT_FLOOR_M,
    INVALID_DEPTH_M,
    FreeBubble,
    InputSpec,
    frame_input,
    scaled_imprint,
)

H, W = 24, 32
FREE_IR = 1500.0


def _free() -> FreeBubble:
    yy, xx = np.mgrid[0:H, 0:W]
    dome = 0.06 + 0.01 * (((yy - H / 2) / H) ** 2 + ((xx - W / 2) / W) ** 2)
    depth = dome.astype(np.float32)
    depth[0, :] = np.nan  # a rim the camera does not see, at rest too
    ir = np.full((H, W), FREE_IR, np.float32)
    ir[0, :] = 0
    return FreeBubble.from_arrays(
        {"depth_left_m": depth, "depth_right_m": depth, "ir_left": ir, "ir_right": ir}, "test"
    )


def _bump() -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return np.exp(-(((yy - 12) / 5.0) ** 2) - ((xx - 14) / 7.0) ** 2)


def _pressed(free: FreeBubble, depth_m: float, ir_gain: float) -> dict[str, np.ndarray]:
    """Both bubbles pressed by the same bump, ``depth_m`` deep, the IR up by
    ``ir_gain`` times the bump; deeper than the minimum range is a hole (NaN)."""
    out = {}
    for side in ("left", "right"):
        depth = getattr(free, f"depth_{side}_m") - depth_m * _bump()
        depth[depth < INVALID_DEPTH_M] = np.nan
        ir = getattr(free, f"ir_{side}") + ir_gain * _bump()
        out[f"depth_{side}_m"] = depth.astype(np.float32)
        out[f"ir_{side}"] = np.where(getattr(free, f"ir_{side}") > 0, ir, 0).astype(np.uint16)
    return out


def _spec(free: FreeBubble, modality: str = "both") -> InputSpec:
    return InputSpec(
        modality=modality, input_px=32, imprint_depth_m=0.025, imprint_ir=2500.0, free=free
    )


def test_a_shallow_and_a_deep_imprint_of_one_shape_give_one_input() -> None:
    free = _free()
    shallow = _pressed(free, 0.008, 600.0)
    deep = _pressed(free, 0.016, 1300.0)
    spec = _spec(free)
    a, b = frame_input(spec, **shallow), frame_input(spec, **deep)
    assert np.isfinite(a).all() and np.isfinite(b).all()
    assert np.allclose(a[0], b[0], atol=1e-4)
    assert np.allclose(a[1], b[1], atol=1e-2)  # the IR's counts are whole numbers
    # Unscaled, the two differ: the depth channel by the dent's depth.
    plain = InputSpec(modality="both", input_px=32)
    assert np.abs(frame_input(plain, **shallow)[0] - frame_input(plain, **deep)[0]).max() > 0.5
    # The scaled dent's 99th percentile is the canonical depth.
    depth, ir = scaled_imprint(
        spec, shallow["depth_left_m"], shallow["ir_left"], free.depth_left_m, free.ir_left
    )
    dent = free.depth_left_m - depth
    assert np.nanquantile(dent, 0.99) == pytest.approx(0.025, rel=1e-3)
    assert np.isnan(depth[0]).all() and (ir[0] == 0).all()  # the unseen rim stays unseen


def test_a_hole_reads_as_the_deepest_part_of_the_dent() -> None:
    # Pressed past the minimum range, the imprint's middle is a hole: it reads as a dent
    # to the minimum range, the top of the scaled dent, not as a far patch.
    free = _free()
    frame = _pressed(free, 0.03, 2000.0)
    assert np.isnan(frame["depth_left_m"][1:]).any()
    depth, _ = scaled_imprint(
        _spec(free), frame["depth_left_m"], frame["ir_left"], free.depth_left_m, free.ir_left
    )
    hole = np.isnan(frame["depth_left_m"]) & np.isfinite(free.depth_left_m)
    dent = free.depth_left_m - depth
    assert np.isfinite(depth[hole]).all()
    assert dent[hole].min() > np.nanquantile(dent[~hole], 0.9)


def test_an_untouched_bubble_is_not_blown_up() -> None:
    # Only noise: the scale stops at the floor, so the noise grows at most by
    # imprint / floor, and the input stays finite.
    free = _free()
    rng = np.random.default_rng(0)
    frame = _pressed(free, 0.0, 0.0)
    noise = rng.normal(0, 0.0003, (H, W)).astype(np.float32)
    frame["depth_left_m"] = frame["depth_left_m"] + noise
    depth, _ = scaled_imprint(
        _spec(free), frame["depth_left_m"], frame["ir_left"], free.depth_left_m, free.ir_left
    )
    grown = np.nanmax(np.abs(free.depth_left_m - depth)) / np.nanmax(np.abs(noise[1:]))
    assert grown == pytest.approx(0.025 / IMPRINT_FLOOR_M, rel=1e-3)


def test_the_imprint_scale_needs_its_free_bubble() -> None:
    with pytest.raises(ValueError, match="needs the free bubble"):
        InputSpec(modality="both", input_px=32, imprint_depth_m=0.025, imprint_ir=2500.0)
    with pytest.raises(ValueError, match="both > 0 or both 0"):
        InputSpec(modality="both", input_px=32, imprint_depth_m=0.025, free=_free())
    with pytest.raises(ValueError, match=r"free.npz: no ir_right"):
        FreeBubble.from_arrays(
            {"depth_left_m": np.zeros(3), "depth_right_m": np.zeros(3), "ir_left": np.zeros(3)},
            "free.npz",
        )
    with pytest.raises(ValueError, match="depth and IR"):
        frame = _pressed(_free(), 0.01, 500.0)
        del frame["ir_left"]
        frame_input(_spec(_free(), "depth"), **frame)


def test_checkpoint_carries_the_imprint_scale_and_free_bubble(tmp_path: Path) -> None:
    free = _free()
    meta = ModelMeta.for_spec(_spec(free), ["a", "b"], 0.125)
    model = build_model(meta)
    save_checkpoint(tmp_path / "m.pt", model, meta, half=True)
    loaded = Classifier.load(tmp_path / "m.pt")
    assert loaded.spec == _spec(free)  # the scale's figures
    assert free.same(loaded.spec.free)
    frame = _pressed(free, 0.01, 800.0)
    want = loaded.probabilities(frame_input(_spec(free), **frame)[None])[0]
    assert np.allclose(loaded.classify(**frame), want)
    # A checkpoint without them (saved before) reads frames unscaled.
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    for key in ("imprint_depth_m", "imprint_ir", "free_bubble"):
        del payload[key]
    torch.save(payload, tmp_path / "old.pt")
    old = load_checkpoint(tmp_path / "old.pt")
    assert old[1].imprint_depth_m == 0 and old[1].free is None
    # Models that read frames differently are not one model: no average.
    with pytest.raises(CheckpointError, match="imprint_depth_m"):
        average([old, load_checkpoint(tmp_path / "m.pt")])
    other = FreeBubble.from_arrays(
        {n: getattr(free, n) + 0.001 for n in ("depth_left_m", "depth_right_m")}
        | {"ir_left": free.ir_left, "ir_right": free.ir_right},
        "other",
    )
    moved = ModelMeta.for_spec(_spec(other), ["a", "b"], 0.125)
    with pytest.raises(CheckpointError, match="free-bubble"):
        average([(model, meta), (build_model(moved), moved)])
    # A free bubble that is not the four frames is refused, naming the file.
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    del payload["free_bubble"]["ir_left"]
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match="bad.pt: .*free_bubble must hold"):
        load_checkpoint(tmp_path / "bad.pt")
