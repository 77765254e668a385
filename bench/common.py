"""What every benchmark shares: the command line, the machine record, tables, JSON, plots.

A benchmark module defines ``run(quick: bool) -> list[dict]`` (rows with unit-suffixed
keys) and calls :func:`main` with it::

    if __name__ == "__main__":
        main("pose", run, columns=[...], plot=plot_rows)

``python -m bench.NAME`` prints a table, ``--json`` prints
``{"machine": {...}, "rows": [...]}``, ``--quick`` runs a small size (smoke tests),
``--plot PATH`` writes the plot (default ``bench/results/NAME.png``).

Long sweeps show where they are: :func:`progress` wraps a sweep's points and prints one
line per point on stderr (what it was, its time, an estimate of the time left), so the
table on stdout stays clean. Graphs a benchmark launches write their chatter to
:func:`launcher_log` (``bench/results/NAME.log``), not into the table.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any, TypeVar

Row = dict[str, Any]
T = TypeVar("T")
RESULTS = Path("bench/results")


def progress(
    points: Iterable[T],
    name: str,
    *,
    label: Callable[[T], str] = str,
    stream: IO[str] | None = None,
) -> Iterator[T]:
    """Yield the sweep's points, printing one line per finished point on ``stream``.

    The line says which point of how many, its label, its time, and the time left
    estimated from the mean time per point so far::

        [bench.shear] 3/12 fb L3 w45 (facts): 4.1 s; 12 s so far, about 37 s left

    Args:
        points: the sweep (a sequence, or any iterable: it is listed first to count it).
        name: the benchmark, e.g. ``"bench.shear"``.
        label: the text that names a point.
        stream: where the lines go (default stderr, so stdout keeps the table or JSON).
    """
    items = list(points)
    out = sys.stderr if stream is None else stream
    start = last = time.monotonic()
    for i, item in enumerate(items, 1):
        yield item
        now = time.monotonic()
        so_far = now - start
        left = so_far / i * (len(items) - i)
        print(
            f"[{name}] {i}/{len(items)} {label(item)}: {now - last:.1f} s; "
            f"{so_far:.0f} s so far, about {left:.0f} s left",
            file=out,
            flush=True,
        )
        last = now


@contextlib.contextmanager
def launcher_log(name: str) -> Iterator[IO[str]]:
    """A file for what the graphs a benchmark launches print (``bench/results/NAME.log``).

    Pass it as the launcher's ``out`` (or redirect stdout to it around ``launch``): the
    table stays readable and the log is there when a graph fails. The first graph of a
    run starts the file; later ones append to it.
    """
    path = RESULTS / f"{name}.log"
    first = path not in _LOGS_STARTED  # one log per benchmark run: later graphs append
    _LOGS_STARTED.add(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w" if first else "a") as log:
        yield log
    if first:
        print(f"[bench.{name}] launcher log: {path}", file=sys.stderr, flush=True)


_LOGS_STARTED: set[Path] = set()


def machine() -> dict[str, Any]:
    """The facts a reader needs to compare figures across runs."""
    import numpy as np

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
    }


def one_core() -> None:
    """Pin the process's numeric libraries to one thread, as the targets say 'one core'."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:
        pass
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass


def median(values: Sequence[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0-100) by linear interpolation; NaN for no values."""
    import numpy as np

    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else float("nan")


def plain_log_ticks(ax: Any, which: str) -> None:
    """Log scale on the ``which`` axes (``"x"``, ``"y"`` or ``"xy"``) of a matplotlib
    ``ax``, labelled at 1-2-3-5 steps in plain numbers: by default matplotlib labels the
    minor ticks of a log axis that spans less than a decade, and those labels overlap."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    steps = [m * 10.0**e for e in range(-4, 6) for m in (1, 2, 3, 5)]
    for name in which:
        getattr(ax, f"set_{name}scale")("log")
        axis = getattr(ax, f"{name}axis")
        axis.set_major_locator(FixedLocator(steps))
        axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        axis.set_minor_formatter(NullFormatter())


def label_points(
    ax: Any, points: Sequence[tuple[float, float]], labels: Sequence[str], fontsize: float = 7
) -> None:
    """Write ``labels`` beside ``points`` (data coordinates) of a matplotlib ``ax`` whose
    limits and layout are final, each where it overlaps no label placed before it and no
    other point: right and up by default, else below, left, or further out."""
    ax.get_xlim(), ax.get_ylim()  # settles autoscaled limits before transforming
    px = ax.figure.dpi / 72.0  # pixels per point
    marker = 4.0 * px  # half the size of a marker
    centres = [tuple(ax.transData.transform(p)) for p in points]
    obstacles = [(x - marker, y - marker, x + marker, y + marker) for x, y in centres]
    height = fontsize * px
    for (x, y), label in zip(centres, labels, strict=True):
        width = 0.62 * fontsize * px * len(label)
        candidates = [
            (dx * px + (-width if dx < 0 else 0.0), dy * px)
            for dy in (3, -10, 10, -17, 17)
            for dx in (4, -4)
        ]
        boxes = [(x + dx, y + dy, x + dx + width, y + dy + height) for dx, dy in candidates]
        free = [
            i
            for i, (x0, y0, x1, y1) in enumerate(boxes)
            if not any(
                x0 < b[2] and b[0] < x1 and y0 < b[3] and b[1] < y1
                for b in obstacles
                if not (b[0] < x < b[2] and b[1] < y < b[3])  # its own point
            )
        ]
        best = free[0] if free else 0
        obstacles.append(boxes[best])
        dx, dy = candidates[best]
        ax.annotate(
            label,
            ax.transData.inverted().transform((x, y)),
            textcoords="offset pixels",
            xytext=(dx, dy),
            fontsize=fontsize,
        )


def format_table(rows: Sequence[Row], columns: Sequence[str] | None = None) -> str:
    """A plain fixed-width table; floats to 4 significant digits."""
    if not rows:
        return "(no rows)"
    columns = list(columns or rows[0].keys())

    def cell(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.4g}"
        return str(value)

    cells = [[cell(r.get(c, "")) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)


def main(
    name: str,
    run: Callable[[bool], list[Row]],
    *,
    columns: Sequence[str] | None = None,
    plot: Callable[[list[Row], Path], None] | None = None,
    argv: Sequence[str] | None = None,
) -> list[Row]:
    """Parse the shared flags, run the sweep, print the table or JSON, write the plot."""
    parser = argparse.ArgumentParser(prog=f"python -m bench.{name}")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quick", action="store_true", help="small sizes, for smoke tests")
    parser.add_argument("--plot", type=Path, default=RESULTS / f"{name}.png")
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    rows = run(args.quick)
    if args.json:
        json.dump({"machine": machine(), "rows": rows}, sys.stdout, default=float)
        sys.stdout.write("\n")
    else:
        print(format_table(rows, columns))
    if plot is not None and not args.no_plot:
        import matplotlib

        matplotlib.use("Agg")
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(rows, args.plot)
        if not args.json:
            print(f"plot: {args.plot}")
    return rows
