"""Parameters of the shear estimate: the flow method, its knobs, the membrane mask."""

from __future__ import annotations

from typing import Annotated, Literal, get_args

import cv2
import msgspec
from msgspec import Meta

DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
FlowMethod = Literal["farneback", "dis"]
FLOW_METHODS: tuple[str, ...] = get_args(FlowMethod)
DisPreset = Literal["ultrafast", "fast", "medium"]


def _require(condition: bool, name: str, value: object, what: str) -> None:
    if not condition:
        raise ValueError(f"`{name}` must be {what}, got {value!r}")


class FarnebackParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Farneback's knobs (``cv2.calcOpticalFlowFarneback``).

    Defaults are OpenCV's sample parameters that docs/facts.md cites (pyramid scale 0.5,
    3 levels, window 15, 3 iterations, poly_n 5, sigma 1.2); ``bench/shear.py`` sweeps them.
    """

    pyr_scale: Annotated[
        float,
        Meta(
            description="each pyramid level's scale against the one below (OpenCV pyr_scale)",
            gt=0.0,
            lt=1.0,
        ),
    ] = 0.5
    levels: Annotated[
        int, Meta(description="pyramid levels, the full image included", ge=1, le=10)
    ] = 3
    winsize: Annotated[
        int,
        Meta(
            description="averaging window (px); larger is more robust to noise, blurs motion",
            ge=3,
            le=201,
        ),
    ] = 15
    iterations: Annotated[
        int, Meta(description="iterations at each pyramid level", ge=1, le=50)
    ] = 3
    poly_n: Annotated[
        Literal[5, 7], Meta(description="pixel neighbourhood of the polynomial expansion")
    ] = 5
    poly_sigma: Annotated[
        float,
        Meta(
            description="Gaussian sigma smoothing the derivatives of the expansion (1.1 for poly_n 5, 1.5 for 7)",
            ge=0.1,
            le=5.0,
        ),
    ] = 1.2
    gaussian_window: Annotated[
        bool,
        Meta(
            description="a Gaussian window instead of a box filter (OpenCV OPTFLOW_FARNEBACK_GAUSSIAN)"
        ),
    ] = False


class DisParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """DIS optical flow: a preset and optional overrides (``None`` keeps the preset's)."""

    preset: Annotated[DisPreset, Meta(description="OpenCV's DIS preset")] = "fast"
    finest_scale: (
        Annotated[
            int, Meta(description="the finest pyramid level computed (0: full resolution)", ge=0)
        ]
        | None
    ) = None
    patch_size: (
        Annotated[int, Meta(description="side of the matched patches (px)", ge=2)] | None
    ) = None
    patch_stride: (
        Annotated[
            int,
            Meta(
                description="distance between neighbouring patches (px), at most patch_size", ge=1
            ),
        ]
        | None
    ) = None
    gradient_descent_iterations: (
        Annotated[int, Meta(description="gradient descent iterations per patch", ge=1)] | None
    ) = None
    variational_iterations: (
        Annotated[int, Meta(description="variational refinement iterations (0: none)", ge=0)] | None
    ) = None

    def __post_init__(self) -> None:
        if self.patch_size is not None and self.patch_stride is not None:
            _require(
                self.patch_stride <= self.patch_size,
                "patch_stride",
                self.patch_stride,
                f"<= patch_size ({self.patch_size})",
            )


class ShearParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Everything the shear estimate depends on."""

    method: Annotated[FlowMethod, Meta(description='``"farneback"`` (the paper) or ``"dis"``.')] = (
        "farneback"
    )
    farneback: Annotated[
        FarnebackParams,
        Meta(description='Farneback\'s knobs (used when ``method == "farneback"``).'),
    ] = msgspec.field(default_factory=FarnebackParams)
    dis: Annotated[DisParams, Meta(description='DIS\'s knobs (used when ``method == "dis"``).')] = (
        msgspec.field(default_factory=DisParams)
    )
    scale: Annotated[
        float,
        Meta(
            ge=0.1,
            le=1.0,
            description=(
                "input scale for the flow: 1.0 full resolution, 0.5 half (area "
                "averaging). Results are always reported in full-resolution pixels."
            ),
        ),
    ] = 1.0
    warm_start: Annotated[
        bool,
        Meta(description="start each frame's flow from the previous frame's (same reference)."),
    ] = False
    border_px: Annotated[
        int, Meta(ge=0, description="full-resolution pixels dropped at each image edge.")
    ] = 4
    min_depth_m: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "nearer depth is invalid. The driver already marks pixels outside its "
                "working range (docs/facts.md: 4-11 cm of *range*) as NaN; z-depth is "
                "shorter than range off-axis, so these bounds are loose and only catch "
                "gross outliers."
            ),
        ),
    ] = 0.01
    max_depth_m: Annotated[float, Meta(description="farther depth is invalid.")] = 0.5
    min_ir: Annotated[
        int,
        Meta(
            ge=0,
            le=65535,
            description="IR below this is invalid (the driver reports invalid pixels as 0).",
        ),
    ] = 1
    saturation_ir: Annotated[
        int, Meta(le=65536, description="IR at or above this is saturated, hence invalid.")
    ] = 65535
    min_magnitude_px: Annotated[
        float, Meta(ge=0, description="below this mean displacement the direction is undefined.")
    ] = 0.05
    min_valid_fraction: Annotated[
        float,
        Meta(
            gt=0.0, le=1.0, description="below this fraction of masked pixels nothing is defined."
        ),
    ] = 0.01

    def __post_init__(self) -> None:
        _require(
            self.max_depth_m > self.min_depth_m,
            "max_depth_m",
            self.max_depth_m,
            f"> min_depth_m ({self.min_depth_m})",
        )
        _require(
            self.saturation_ir > self.min_ir,
            "saturation_ir",
            self.saturation_ir,
            f"> min_ir ({self.min_ir})",
        )
