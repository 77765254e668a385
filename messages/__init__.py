"""The graph's vocabulary: typed messages, the frame codec, schema fingerprints."""

from __future__ import annotations

from messages.base import Array, Header, Message, describe, message_type
from messages.codec import decode, decode_header, encode
from messages.errors import FingerprintMismatchError, FrameDecodeError
from messages.types import (
    ClassProbabilities,
    ContactPatch,
    GraspState,
    GripperCommand,
    GripperState,
    GroundTruth,
    MaskImage,
    OverlayImage,
    PoseEstimate,
    Pressure,
    ShearEstimate,
    TaskEvent,
    Tick,
    ToFImage,
)

__all__ = [
    "Array",
    "ClassProbabilities",
    "ContactPatch",
    "FingerprintMismatchError",
    "FrameDecodeError",
    "GraspState",
    "GripperCommand",
    "GripperState",
    "GroundTruth",
    "Header",
    "MaskImage",
    "Message",
    "OverlayImage",
    "PoseEstimate",
    "Pressure",
    "ShearEstimate",
    "TaskEvent",
    "Tick",
    "ToFImage",
    "decode",
    "decode_header",
    "describe",
    "encode",
    "message_type",
]

# Message types declared in other modules of this package (one per area) register on
# import; import them all so every process knows every type.
import importlib as _importlib  # noqa: E402
import pkgutil as _pkgutil  # noqa: E402

for _module in _pkgutil.iter_modules(__path__):
    _importlib.import_module(f"{__name__}.{_module.name}")
