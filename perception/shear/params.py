"""Parameters of the shear estimate: the flow method, its knobs, the membrane mask."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2

DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
FLOW_METHODS = ("farneback", "dis")


def _require(condition: bool, name: str, value: object, what: str) -> None:
    if not condition:
        raise ValueError(f"`{name}` must be {what}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class FarnebackParams:
    """Farneback's knobs (``cv2.calcOpticalFlowFarneback``).

    Defaults are OpenCV's sample parameters that docs/facts.md cites (pyramid scale 0.5,
    3 levels, window 15, 3 iterations, poly_n 5, sigma 1.2); ``bench/shear.py`` sweeps them.
    """

    pyr_scale: float = 0.5
    levels: int = 3
    winsize: int = 15
    iterations: int = 3
    poly_n: int = 5
    poly_sigma: float = 1.2
    gaussian_window: bool = False

    def __post_init__(self) -> None:
        _require(0.0 < self.pyr_scale < 1.0, "pyr_scale", self.pyr_scale, "in (0, 1)")
        _require(1 <= self.levels <= 10, "levels", self.levels, "in [1, 10]")
        _require(3 <= self.winsize <= 201, "winsize", self.winsize, "in [3, 201]")
        _require(1 <= self.iterations <= 50, "iterations", self.iterations, "in [1, 50]")
        _require(self.poly_n in (5, 7), "poly_n", self.poly_n, "5 or 7")
        _require(0.1 <= self.poly_sigma <= 5.0, "poly_sigma", self.poly_sigma, "in [0.1, 5]")


@dataclass(frozen=True, kw_only=True)
class DisParams:
    """DIS optical flow: a preset and optional overrides (``None`` keeps the preset's)."""

    preset: str = "fast"
    finest_scale: int | None = None
    patch_size: int | None = None
    patch_stride: int | None = None
    gradient_descent_iterations: int | None = None
    variational_iterations: int | None = None

    def __post_init__(self) -> None:
        _require(self.preset in DIS_PRESETS, "preset", self.preset, f"one of {sorted(DIS_PRESETS)}")
        for name, low in (
            ("finest_scale", 0),
            ("patch_size", 2),
            ("patch_stride", 1),
            ("gradient_descent_iterations", 1),
            ("variational_iterations", 0),
        ):
            value = getattr(self, name)
            _require(value is None or value >= low, name, value, f"None or >= {low}")
        if self.patch_size is not None and self.patch_stride is not None:
            _require(
                self.patch_stride <= self.patch_size,
                "patch_stride",
                self.patch_stride,
                f"<= patch_size ({self.patch_size})",
            )


@dataclass(frozen=True, kw_only=True)
class ShearParams:
    """Everything the shear estimate depends on.

    Attributes:
        method: ``"farneback"`` (the paper) or ``"dis"``.
        farneback: Farneback's knobs (used when ``method == "farneback"``).
        dis: DIS's knobs (used when ``method == "dis"``).
        scale: input scale for the flow: 1.0 full resolution, 0.5 half (area averaging).
            Results are always reported in full-resolution pixels.
        warm_start: start each frame's flow from the previous frame's (same reference).
        border_px: full-resolution pixels dropped at each image edge.
        min_depth_m: nearer depth is invalid. The driver already marks pixels outside
            its working range (docs/facts.md: 4-11 cm of *range*) as NaN; z-depth is shorter
            than range off-axis, so these bounds are loose and only catch gross outliers.
        max_depth_m: farther depth is invalid.
        min_ir: IR below this is invalid (the driver reports invalid pixels as 0).
        saturation_ir: IR at or above this is saturated, hence invalid.
        min_magnitude_px: below this mean displacement the direction is undefined.
        min_valid_fraction: below this fraction of masked pixels nothing is defined.
    """

    method: str = "farneback"
    farneback: FarnebackParams = field(default_factory=FarnebackParams)
    dis: DisParams = field(default_factory=DisParams)
    scale: float = 1.0
    warm_start: bool = False
    border_px: int = 4
    min_depth_m: float = 0.01
    max_depth_m: float = 0.5
    min_ir: int = 1
    saturation_ir: int = 65535
    min_magnitude_px: float = 0.05
    min_valid_fraction: float = 0.01

    def __post_init__(self) -> None:
        _require(self.method in FLOW_METHODS, "method", self.method, f"one of {FLOW_METHODS}")
        _require(0.1 <= self.scale <= 1.0, "scale", self.scale, "in [0.1, 1]")
        _require(self.border_px >= 0, "border_px", self.border_px, ">= 0")
        _require(self.min_depth_m >= 0.0, "min_depth_m", self.min_depth_m, ">= 0")
        _require(
            self.max_depth_m > self.min_depth_m,
            "max_depth_m",
            self.max_depth_m,
            f"> min_depth_m ({self.min_depth_m})",
        )
        _require(0 <= self.min_ir <= 65535, "min_ir", self.min_ir, "in [0, 65535]")
        _require(
            self.min_ir < self.saturation_ir <= 65536,
            "saturation_ir",
            self.saturation_ir,
            f"in ({self.min_ir}, 65536]",
        )
        _require(self.min_magnitude_px >= 0.0, "min_magnitude_px", self.min_magnitude_px, ">= 0")
        _require(
            0.0 < self.min_valid_fraction <= 1.0,
            "min_valid_fraction",
            self.min_valid_fraction,
            "in (0, 1]",
        )
