"""What every benchmark shares: the command line, the machine record, tables, JSON, plots.

A benchmark module defines ``run(quick: bool) -> list[dict]`` (rows with unit-suffixed
keys) and calls :func:`main` with it::

    if __name__ == "__main__":
        main("pose", run, columns=[...], plot=plot_rows)

``python -m bench.NAME`` prints a table, ``--json`` prints
``{"machine": {...}, "rows": [...]}``, ``--quick`` runs a small size (smoke tests),
``--plot PATH`` writes the plot (default ``bench/results/NAME.png``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

Row = dict[str, Any]


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
    parser.add_argument("--plot", type=Path, default=Path("bench/results") / f"{name}.png")
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
