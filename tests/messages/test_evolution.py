"""Schema evolution: a stored message of an older declaration of its type.

A bag keeps each type's description beside its messages. A message whose stored
declaration lacks fields that today's declaration gives a default decodes, the defaults
filled in; a field today's type no longer has, a field whose type changed, or a missing
field without a default is refused, naming the type and the field. The live wire carries
no description and keeps refusing any other fingerprint.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import msgspec
import numpy as np
import pytest

from messages import FingerprintMismatchError, FrameDecodeError, Header, decode, encode
from messages.base import Array, Message
from messages.errors import SchemaChangeError
from messages.evolution import check_stored
from tests.messages.declare import declare

Image = Annotated[np.ndarray, Array("float32", (None, None))]
BASE: list[tuple[str, Any]] = [("header", Header), ("width_m", float), ("image", Image)]
OLD_HEADER = msgspec.defstruct("Header", [("stamp_nanos", int, 0), ("seq", int, 0)], kw_only=True)


def stored(old: type[Message], **extra: Any) -> tuple[list[Any], dict[str, Any]]:
    """Frames of a message of the older declaration ``old``, and its stored description."""
    header = msgspec.convert({"seq": 3, "stamp_nanos": 7}, dict(old.__annotations__)["header"])
    msg = old(header=header, width_m=0.05, image=np.ones((2, 3), np.float32), **extra)
    return encode("probe/out", msg), old.schema().description


def test_fields_added_with_defaults_are_filled_in(scratch_registry: dict) -> None:
    old = declare("EvoProbe", BASE)
    today = declare(
        "EvoProbe",
        [
            *BASE,
            ("force_n", float, 20.0),
            ("labels", list[str], msgspec.field(default_factory=lambda: ["none"])),
            (
                "mask",
                Annotated[np.ndarray, Array("uint8", (None,))],
                msgspec.field(default_factory=lambda: np.zeros(0, np.uint8)),
            ),
        ],
        keep=True,
    )
    frames, description = stored(old)
    # The live wire has no description: another fingerprint is refused, as always.
    with pytest.raises(FingerprintMismatchError, match=old.schema().fingerprint):
        decode(frames)
    _, msg = decode(frames, stored=description)
    assert type(msg) is today
    assert msg.width_m == 0.05 and msg.header.seq == 3 and msg.header.stamp_nanos == 7
    np.testing.assert_array_equal(msg.image, np.ones((2, 3), np.float32))
    assert msg.force_n == 20.0 and msg.labels == ["none"]
    assert msg.mask.dtype == np.uint8 and msg.mask.shape == (0,)
    # Today's own frames still decode with or without a description.
    again = encode("probe/out", msg)
    assert decode(again, stored=today.schema().description)[1].force_n == 20.0


def test_a_nested_struct_that_gained_a_defaulted_field(scratch_registry: dict) -> None:
    old = declare("EvoProbe", [("header", OLD_HEADER), *BASE[1:]])
    declare("EvoProbe", BASE, keep=True)  # today's Header has frame_id = ""
    frames, description = stored(old)
    _, msg = decode(frames, stored=description)
    assert msg.header == Header(stamp_nanos=7, seq=3, frame_id="")


REFUSED: dict[str, tuple[list[tuple[str, Any]], list[tuple[str, Any]], dict[str, Any], str]] = {
    # name: (stored declaration, today's, extra values of the stored message, error)
    "field removed since": (
        [*BASE, ("force_n", float)],
        BASE,
        {"force_n": 1.0},
        r"EvoProbe\.force_n: stored, but today's EvoProbe has no such field",
    ),
    "field retyped": (
        BASE,
        [("header", Header), ("width_m", int), ("image", Image)],
        {},
        r"EvoProbe\.width_m: stored as float, today int",
    ),
    "array retyped": (
        BASE,
        [*BASE[:2], ("image", Annotated[np.ndarray, Array("float64", (None, None))])],
        {},
        r"EvoProbe\.image: stored as array <f4 \[None, None\], today array <f8 \[None, None\]",
    ),
    "field added without a default": (
        BASE,
        [*BASE, ("force_n", float)],
        {},
        r"EvoProbe\.force_n: not in the stored message, and today's EvoProbe gives it no default",
    ),
    "nested field removed since": (
        [
            (
                "header",
                msgspec.defstruct("Header", [("seq", int, 0), ("clock", str, "")], kw_only=True),
            ),
            *BASE[1:],
        ],
        BASE,
        {},
        r"EvoProbe\.header\.clock: stored, but today's EvoProbe has no such field",
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_other_changes_are_refused_naming_type_and_field(case: str, scratch_registry: dict) -> None:
    then, now, extra, error = REFUSED[case]
    old = declare("EvoProbe", then)
    declare("EvoProbe", now, keep=True)
    header_type = dict(then)["header"]
    msg = old(header=header_type(), width_m=0.05, image=np.ones((2, 3), np.float32), **extra)
    with pytest.raises(SchemaChangeError, match=error) as info:
        decode(encode("probe/out", msg), stored=old.schema().description)
    # One family: whoever catches a fingerprint mismatch catches this too.
    assert isinstance(info.value, FingerprintMismatchError)
    assert old.schema().fingerprint in str(info.value)


def test_a_description_that_is_not_its_fingerprint_is_refused(scratch_registry: dict) -> None:
    old = declare("EvoProbe", BASE)
    today = declare("EvoProbe", [*BASE, ("force_n", float, 20.0)], keep=True)
    frames, description = stored(old)
    forged = {**description, "fields": [*description["fields"], ["force_n", "float"]]}
    with pytest.raises(SchemaChangeError, match="does not match its fingerprint"):
        decode(frames, stored=forged)
    with pytest.raises(SchemaChangeError, match="no stored description"):
        check_stored(today, old.schema().fingerprint, None)
    check_stored(today, today.schema().fingerprint, None)  # today's own: nothing to check


def test_a_str_narrowed_to_choices_reads_each_stored_value_against_them(
    scratch_registry: dict,
) -> None:
    old = declare("EvoProbe", [*BASE, ("sensor", str)])
    declare("EvoProbe", [*BASE, ("sensor", Literal["left", "right"])], keep=True)
    frames, description = stored(old, sensor="left")
    assert decode(frames, stored=description)[1].sensor == "left"
    frames, description = stored(old, sensor="middle")
    with pytest.raises(FrameDecodeError, match=r"Invalid enum value 'middle' - at `\$\.sensor`"):
        decode(frames, stored=description)


def test_choices_widened_or_retyped_are_still_refused(scratch_registry: dict) -> None:
    old = declare("EvoProbe", [*BASE, ("sensor", Literal["left", "right"])])
    declare("EvoProbe", [*BASE, ("sensor", str)], keep=True)
    frames, description = stored(old, sensor="left")
    with pytest.raises(SchemaChangeError, match=r"EvoProbe\.sensor: stored as Literal"):
        decode(frames, stored=description)
