"""What a message field means beyond its type: its unit and a note.

Units come from the field name's suffix (``_m``, ``_pa``, ``_nanos``...); :data:`NOTES`
adds what a name cannot say. Bags store these next to each channel
(``runtime.bag.schema``); the Foxglove and ROS 2 exports put them in their schemas.
"""

from __future__ import annotations

# Name suffix -> unit (longest suffix first wins).
UNITS = {
    "_m_per_s": "m/s",
    "_nanos": "ns",
    "_secs": "s",
    "_hz": "Hz",
    "_rad": "rad",
    "_pa": "Pa",
    "_px": "px",
    "_mm": "mm",
    "_m": "m",
    "_n": "N",
    "_k": "K",
}

JS_INT = (
    "up to 64 bits: values above 2^53 (every wall-clock stamp_nanos) lose precision as a "
    "JavaScript number; decode with BigInt (@msgpack/msgpack: useBigInt64: true)"
)

# What a field's name and type cannot say. Keys are field names (any type), or
# "Type.field" for one type only; ``tests/runtime/test_bag_formats.py`` checks that each
# still names a declared field.
NOTES: dict[str, str] = {
    "stamp_nanos": "nanoseconds since the Unix epoch (simulation: scene time); " + JS_INT,
    "seq": "per-output sequence number, from 0; a gap means messages were dropped",
    "frame_id": "the coordinate frame of the data: tool, left_sensor, right_sensor or object",
    "sensor": "'left' or 'right' (which bubble)",
    "depth_m": "NaN = invalid pixel (no time-of-flight return); row 0 is the top of the image",
    "ir": "time-of-flight amplitude in raw sensor counts (no unit); row 0 is the top",
    "mask": "255 = selected pixel, 0 = not selected",
    "OverlayImage.image": "8-bit colour, channels in B, G, R order (OpenCV); row 0 is the top",
    "points_in_tool": "rows of (x, y, z) in the tool frame, metres",
    "bubble": "per point of points_in_tool: 0 = left bubble, 1 = right bubble",
    "shear_px": "mean membrane displacement (dx, dy) in full-resolution image pixels",
    "direction": "shear_px / magnitude_px, or (0, 0) when direction_defined is false",
    "observable": "which of (tx, ty, tz, rx, ry, rz) in the object frame the patch constrains",
    "probabilities": "one per entry of classes, in that order; they sum to 1",
}

POSE_NOTE = (
    "4x4 homogeneous transform a_from_b (row-major): maps a point in frame b to frame a, "
    "p_in_a = a_from_b @ p_in_b; rotation block orthonormal, translation in metres"
)


def unit_of(name: str) -> str | None:
    """The unit a field's name ends in (``width_m`` -> ``m``), or ``None``."""
    for suffix, unit in UNITS.items():
        if name.endswith(suffix):
            return unit
    return None


def meaning(type_name: str, name: str) -> dict[str, str]:
    """The ``unit`` and ``note`` of a field, where its name or :data:`NOTES` give them."""
    out = {}
    unit = unit_of(name)
    if unit:
        out["unit"] = unit
    note = NOTES.get(f"{type_name}.{name}") or NOTES.get(name)
    if note is None and "_from_" in name:
        note = POSE_NOTE
    if note:
        out["note"] = note
    return out
