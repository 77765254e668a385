"""ResNet18 shapes and knobs; preprocessing of frame pairs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from perception.classify.model import ResNet18, parameter_count, stage_channels
from perception.classify.preprocess import (
    DEPTH_CENTER_M,
    DEPTH_SCALE_M,
    INVALID_DEPTH_M,
    InputSpec,
    channels,
    frame_input,
    normalise_ir,
)


def test_full_width_is_the_standard_resnet18() -> None:
    # torchvision's resnet18 has 11,689,512 parameters for 3 channels and 1000 classes.
    model = ResNet18(1000, in_channels=3, width=1.0)
    assert parameter_count(model) == 11_689_512


def test_half_width_has_about_a_quarter_of_the_parameters() -> None:
    full = parameter_count(ResNet18(4, in_channels=1, width=1.0))
    half = parameter_count(ResNet18(4, in_channels=1, width=0.5))
    assert 0.2 < half / full < 0.3
    assert stage_channels(0.5) == (32, 64, 128, 256)


@pytest.mark.parametrize("px", [32, 112])
@pytest.mark.parametrize("in_channels", [1, 2])
def test_logits_shape(px: int, in_channels: int) -> None:
    model = ResNet18(4, in_channels=in_channels, width=0.125).eval()
    out = model(torch.zeros(3, in_channels, px, px))
    assert out.shape == (3, 4)
    assert torch.isfinite(out).all()


def test_bad_knobs_are_refused() -> None:
    with pytest.raises(ValueError, match="width"):
        ResNet18(4, width=0)
    with pytest.raises(ValueError, match="num_classes"):
        ResNet18(1)
    with pytest.raises(ValueError, match="modality"):
        InputSpec(modality="rgb", input_px=112)
    with pytest.raises(ValueError, match="input_px"):
        InputSpec(modality="depth", input_px=8)


def _pair(h: int = 20, w: int = 30) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    depth = (0.08 + rng.normal(0, 0.001, (h, w))).astype(np.float32)
    ir = rng.integers(100, 5000, (h, w)).astype(np.uint16)
    return {"depth_left_m": depth, "depth_right_m": depth.copy(), "ir_left": ir, "ir_right": ir}


@pytest.mark.parametrize("modality", ["depth", "ir", "both"])
def test_frame_input_channels_and_size(modality: str) -> None:
    spec = InputSpec(modality=modality, input_px=40)
    x = frame_input(spec, **_pair())
    assert x.shape == (channels(modality), 40, 40)
    assert x.dtype == np.float32
    assert np.isfinite(x).all()


def test_left_is_left_and_right_is_right() -> None:
    pair = _pair()
    pair["depth_left_m"] = np.full_like(pair["depth_left_m"], 0.06)
    pair["depth_right_m"] = np.full_like(pair["depth_right_m"], 0.09)
    x = frame_input(InputSpec(modality="depth", input_px=32), **pair)[0]
    assert np.allclose(x[:, :14], (0.06 - DEPTH_CENTER_M) / DEPTH_SCALE_M)
    assert np.allclose(x[:, 18:], (0.09 - DEPTH_CENTER_M) / DEPTH_SCALE_M)


def test_nan_depth_and_dark_ir_stay_finite() -> None:
    pair = _pair()
    pair["depth_left_m"][:] = np.nan
    pair["ir_left"][:] = 0
    pair["ir_right"][:] = 0
    x = frame_input(InputSpec(modality="both", input_px=32), **pair)
    assert np.isfinite(x).all()
    assert np.all(x[1] == 0)  # no valid IR: no information, zeros
    left, right = normalise_ir(np.full((4, 4), 7, np.uint16), np.full((4, 4), 7, np.uint16))
    assert np.all(left == 0) and np.all(right == 0)  # constant image: zero variance guarded


def test_invalid_depth_reads_as_the_minimum_range() -> None:
    # A hole (membrane nearer than the ToF's minimum range) reads as that range, as a
    # dent at 40 mm would; a spec of an older model reads it as the centre (input 0).
    pair = _pair()
    pair["depth_left_m"][:] = np.nan
    pair["depth_right_m"][:] = INVALID_DEPTH_M
    x = frame_input(InputSpec(modality="depth", input_px=32), **pair)[0]
    assert INVALID_DEPTH_M == 0.04
    assert np.allclose(x, (INVALID_DEPTH_M - DEPTH_CENTER_M) / DEPTH_SCALE_M)
    old = InputSpec(modality="depth", input_px=32, invalid_depth_m=DEPTH_CENTER_M)
    assert np.all(frame_input(old, **pair)[0][:, :14] == 0)
    with pytest.raises(ValueError, match="invalid_depth_m"):
        InputSpec(modality="depth", input_px=32, invalid_depth_m=0.0)


def test_missing_channel_is_an_error() -> None:
    pair = _pair()
    with pytest.raises(ValueError, match="ir_left"):
        frame_input(
            InputSpec(modality="ir", input_px=32),
            depth_left_m=pair["depth_left_m"],
            depth_right_m=pair["depth_right_m"],
        )
