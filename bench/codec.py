"""The frame codec alone: microseconds per ``encode`` and ``decode``, in one process.

Messages: a ``ToFImage`` of one sensor (172 x 224 float32 depth and uint16 IR, the
frame every camera node sends), a ``PoseEstimate`` (a fixed 4 x 4 array and scalars) and
a ``Pressure`` (scalars only). Array layouts: ``ready`` (C-contiguous, little-endian, of
the declared dtype: what numpy makes, and the encoder's fast path), ``big_endian`` and
``fortran`` (the slow path: checked against the declaration, then byte-swapped or made
contiguous, a copy). The frames of every layout are the same bytes.

``decode`` runs on the frames as ``recv_multipart`` returns them: ``bytes``
(``copy=True``) and ``zmq.Frame`` (``copy=False``, what the runtime receives).

Each figure is the time of one call averaged over ``calls`` calls; rows report the best
(the least disturbed by other processes on the machine) and the median of ``repeats``
such passes, every input of a message interleaved in each pass. ``vs_first_input``
divides a row's best time by that of the same message and operation's first input
(``ready`` for encode, ``bytes`` for decode).

    python -m bench.codec [--quick] [--json]
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zmq

from bench.common import Row, main, median, progress
from messages import Header, Message, PoseEstimate, Pressure, ToFImage, decode, encode

ROWS, COLS = 172, 224
TOPIC = "bench/codec"
STAMP_NANOS = 1_700_000_000_000_000_000  # fixed: every layout must give the same frames
Layout = Callable[[np.ndarray], np.ndarray]  # the same values in another memory layout
LAYOUTS: dict[str, Layout] = {
    "ready": lambda a: a,
    "big_endian": lambda a: a.astype(a.dtype.newbyteorder(">")),
    "fortran": np.asfortranarray,
}


def tof_image(layout: Layout) -> ToFImage:
    """One sensor's frame at the camera's resolution, its images in ``layout``."""
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.04, 0.11, (ROWS, COLS)).astype(np.float32)
    ir = rng.integers(0, 2**16, (ROWS, COLS), dtype=np.uint16)
    return ToFImage(
        header=Header(stamp_nanos=STAMP_NANOS, seq=1, frame_id="left_tof"),
        sensor="left",
        depth_m=layout(depth),
        ir=layout(ir),
        fx_px=200.0,
        fy_px=200.0,
        cx_px=112.0,
        cy_px=86.0,
    )


def pose_estimate(layout: Layout) -> PoseEstimate:
    """A pose fit's result, its 4 x 4 pose in ``layout``."""
    tool_from_object = np.eye(4)
    tool_from_object[:3, 3] = (0.01, -0.02, 0.15)
    return PoseEstimate(
        header=Header(stamp_nanos=STAMP_NANOS, seq=1, frame_id="tool"),
        tool_from_object=layout(tool_from_object),
        residual_rms_m=0.0004,
        cost=0.02,
        iterations=9,
        status="ok",
        solve_secs=0.003,
        points_used=900,
    )


def pressure(layout: Layout) -> Pressure:
    """A pressure reading (no arrays: ``layout`` is unused)."""
    del layout
    return Pressure(header=Header(stamp_nanos=STAMP_NANOS, seq=1), sensor="left", pressure_pa=1e3)


# Each message type, how to make one in a layout, and the layouts that apply to it.
CASES: dict[str, tuple[Callable[[Layout], Message], tuple[str, ...]]] = {
    "ToFImage": (tof_image, tuple(LAYOUTS)),
    "PoseEstimate": (pose_estimate, tuple(LAYOUTS)),
    "Pressure": (pressure, ("ready",)),
}


def per_call_us(call: Callable[[], Any], calls: int) -> float:
    """The mean wall time of one ``call()`` over ``calls`` calls, in microseconds."""
    start = time.perf_counter_ns()
    for _ in range(calls):
        call()
    return (time.perf_counter_ns() - start) / calls / 1e3


def run(quick: bool) -> list[Row]:
    """Every message, operation and input, ``repeats`` interleaved passes, as table rows."""
    calls, repeats = (500, 3) if quick else (20_000, 5)
    rows: list[Row] = []
    for name, (make, layouts) in progress(CASES.items(), "bench.codec", label=lambda c: c[0]):
        msgs = {layout: make(LAYOUTS[layout]) for layout in layouts}
        wire = [bytes(f) for f in encode(TOPIC, msgs["ready"])]
        for layout, msg in msgs.items():
            if [bytes(f) for f in encode(TOPIC, msg)] != wire:
                raise AssertionError(f"{name} {layout}: frames differ from the ready layout's")
        calls_by_input: dict[tuple[str, str], Callable[[], Any]] = {
            ("encode", layout): functools.partial(encode, TOPIC, msg)
            for layout, msg in msgs.items()
        }
        calls_by_input["decode", "bytes"] = functools.partial(decode, wire)
        calls_by_input["decode", "zmq.Frame"] = functools.partial(
            decode, [zmq.Frame(f) for f in wire]
        )
        times: dict[tuple[str, str], list[float]] = {key: [] for key in calls_by_input}
        for _ in range(repeats):
            for key, call in calls_by_input.items():
                times[key].append(per_call_us(call, calls))
        first_us: dict[str, float] = {}
        for (op, given), us in times.items():
            first_us.setdefault(op, min(us))
            rows.append(
                {
                    "message": name,
                    "op": op,
                    "input": given,
                    "frame_bytes": sum(len(f) for f in wire),
                    "us_best": min(us),
                    "us_median": median(us),
                    "vs_first_input": min(us) / first_us[op],
                    "calls": calls,
                    "repeats": repeats,
                }
            )
    return rows


COLUMNS = [
    "message",
    "op",
    "input",
    "frame_bytes",
    "us_best",
    "us_median",
    "vs_first_input",
]

if __name__ == "__main__":
    main("codec", run, columns=COLUMNS)
