"""The finite check a publisher runs on every message (``Message.nonfinite_fields``).

Property tests: whatever the values, layout and dtype, a field is reported exactly when
one of its elements is NaN (outside ``nan_marks_invalid``) or infinite, compared with an
element-by-element reference; integer arrays are never reported.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from messages.base import Array, Header, Message
from messages.types import ToFImage


class FiniteProbe(Message):
    """Float and integer arrays and a scalar that must be finite; ``depth`` may hold NaN."""

    depth: Annotated[np.ndarray, Array("float32", (None, None))]
    force: Annotated[np.ndarray, Array("float64", (None,))]
    half: Annotated[np.ndarray, Array("float16", (None,))]
    counts: Annotated[np.ndarray, Array("uint16", (None,))]
    gain: float

    finite_fields: ClassVar[tuple[str, ...]] = ("depth", "force", "half", "counts", "gain")
    nan_marks_invalid: ClassVar[frozenset[str]] = frozenset({"depth"})


del Message.registry["FiniteProbe"]  # a throwaway: tests that walk the registry never meet it

SPECIALS = (math.nan, math.inf, -math.inf)


def _bad(values: np.ndarray, nan_ok: bool) -> bool:
    """The reference: element by element, in Python."""
    for x in values.ravel().tolist():
        if math.isinf(x) or (math.isnan(x) and not nan_ok):
            return True
    return False


@st.composite
def _float_array(draw: st.DrawFn, dtype: str, ndim: int) -> np.ndarray:
    """Finite values with NaN and infinities sprinkled in at drawn places (or none),
    in a drawn layout: C order, Fortran order, strided or big-endian."""
    shape = draw(hnp.array_shapes(min_dims=ndim, max_dims=ndim, min_side=0, max_side=12))
    values = draw(
        hnp.arrays(dtype, shape, elements=st.floats(-1e3, 1e3, width=np.dtype(dtype).itemsize * 8))
    )
    flat = values.reshape(-1)
    for _ in range(draw(st.integers(0, 3)) if flat.size else 0):
        flat[draw(st.integers(0, flat.size - 1))] = draw(st.sampled_from(SPECIALS))
    layout = draw(st.sampled_from(["C", "F", "strided", "big-endian"]))
    if layout == "F":
        return np.asfortranarray(values)
    if layout == "strided":
        return np.repeat(values, 2, axis=-1)[..., ::2]
    if layout == "big-endian":
        return values.astype(values.dtype.newbyteorder(">"))
    return values


@settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    depth=_float_array("float32", 2),
    force=_float_array("float64", 1),
    half=_float_array("float16", 1),
    counts=hnp.arrays(np.uint16, st.integers(0, 50)),
    gain=st.floats(allow_nan=True, allow_infinity=True),
)
def test_every_nan_and_infinity_is_found_and_nothing_else(
    depth: np.ndarray, force: np.ndarray, half: np.ndarray, counts: np.ndarray, gain: float
) -> None:
    msg = FiniteProbe(depth=depth, force=force, half=half, counts=counts, gain=gain)
    want = [
        name
        for name, bad in (
            ("depth", _bad(depth, nan_ok=True)),
            ("force", _bad(force, nan_ok=False)),
            ("half", _bad(half, nan_ok=False)),
            ("counts", False),
            ("gain", not math.isfinite(gain)),
        )
        if bad
    ]
    assert msg.nonfinite_fields() == want


def test_one_infinite_pixel_among_nan_ones_is_found() -> None:
    """The camera's case: many invalid (NaN) pixels are fine, one infinite one is not."""
    depth = np.full((172, 224), 0.05, np.float32)
    depth[::3, ::5] = np.nan
    ir = np.zeros((172, 224), np.uint16)
    frame = ToFImage(
        header=Header(), sensor="left", depth_m=depth, ir=ir,
        fx_px=200.0, fy_px=200.0, cx_px=112.0, cy_px=86.0,
    )  # fmt: skip
    assert frame.nonfinite_fields() == []
    depth[171, 223] = -np.inf
    assert frame.nonfinite_fields() == ["depth_m"]


def _frame(**numbers: float) -> ToFImage:
    values = {"fx_px": 200.0, "fy_px": 200.0, "cx_px": 112.0, "cy_px": 86.0, **numbers}
    return ToFImage(
        header=Header(), sensor="left", depth_m=np.full((4, 5), 0.05, np.float32),
        ir=np.zeros((4, 5), np.uint16), **values,
    )  # fmt: skip


def test_numbers_whose_sum_overflows_are_finite() -> None:
    """The numbers are checked by their sum first: finite numbers whose sum overflows to
    infinity send the message to the field-by-field pass, which finds nothing."""
    assert math.isinf(sum([1.7e308, 1.7e308]))
    assert _frame(fx_px=1.7e308, fy_px=1.7e308).nonfinite_fields() == []
    assert _frame(fx_px=-1.7e308, cy_px=-1.7e308).nonfinite_fields() == []


def test_infinities_that_cancel_in_a_sum_are_each_named() -> None:
    """inf + -inf is NaN (math.fsum raises): both fields are named, in declaration order."""
    frame = _frame(cy_px=-math.inf, fx_px=math.inf)
    assert frame.nonfinite_fields() == ["fx_px", "cy_px"]
    assert _frame(fy_px=math.nan).nonfinite_fields() == ["fy_px"]


def test_a_number_field_holding_an_array_is_checked_as_an_array() -> None:
    """A field declared a number is checked by what it holds (as before the sum)."""
    assert _frame(cx_px=np.array([1.0, 2.0])).nonfinite_fields() == []  # type: ignore[arg-type]
    bad = _frame(cx_px=np.array([1.0, math.inf]))  # type: ignore[arg-type]
    assert bad.nonfinite_fields() == ["cx_px"]
