"""Every sweep of ``bench/`` in one page: ``docs/performance.md``.

    python -m bench.report                       # every sweep, full size; writes docs/performance.md
    python -m bench.report --quick --out /tmp/perf.md --only codec,shear

Each sweep runs as ``python -m bench.NAME --json --no-plot`` in its own process (the
command that reproduces its table), one progress line each. Sweeps are found, not
listed: every module of ``bench/`` with a ``run`` function, in :data:`ORDER` first.
The page gives the machine, each table, a plot of error against time per algorithm with
its Pareto front (:data:`PARETO`), the setting the default graph uses, and the tactile
classifier's accuracy on a small held-out set the report makes itself
(:mod:`bench.heldout`). Page layout and plots: :mod:`bench.report_page`.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import bench
from bench.common import machine
from bench.report_page import Sweep

ROOT = Path(__file__).resolve().parents[1]
ORDER = (
    "transport",
    "hosts",
    "codec",
    "bags",
    "sim",
    "pose",
    "shear",
    "classifier",
    "tasks",
    "drivers",
    "startup",
)
# Not sweeps: helpers, and bench.pose_hard, whose rows bench.pose already carries.
NOT_SWEEPS = {"common", "report", "report_page", "heldout", "pose_hard"}


def discover() -> list[str]:
    """The sweeps in ``bench/``: modules defining ``run``, :data:`ORDER` first."""
    names = []
    for module in pkgutil.iter_modules(bench.__path__):
        if module.name in NOT_SWEEPS or module.name.startswith("_"):
            continue
        source = Path(bench.__path__[0]) / f"{module.name}.py"
        if source.is_file() and "\ndef run(" in source.read_text():
            names.append(module.name)
    rank = {name: i for i, name in enumerate(ORDER)}
    return sorted(names, key=lambda n: (rank.get(n, len(ORDER)), n))


def columns_of(name: str) -> list[str] | None:
    """The module's ``COLUMNS`` (the table it prints), if it declares them."""
    try:
        module = importlib.import_module(f"bench.{name}")
    except ImportError:
        return None
    cols = getattr(module, "COLUMNS", None)
    return list(cols) if cols else None


def run_sweep(name: str, quick: bool, timeout_secs: float) -> Sweep:
    """Run one sweep in its own process and parse its JSON."""
    args = ["-m", f"bench.{name}", "--json", "--no-plot", *(["--quick"] if quick else [])]
    command = "python " + " ".join(a for a in args if a not in ("--json", "--no-plot"))
    sweep = Sweep(name=name, command=command, columns=columns_of(name))
    start = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, *args],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=timeout_secs,
        )
    except subprocess.TimeoutExpired:
        sweep.secs = time.perf_counter() - start
        sweep.error = f"did not finish in {timeout_secs:.0f} s"
        return sweep
    sweep.secs = time.perf_counter() - start
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        sweep.error = f"exit code {proc.returncode}: " + " / ".join(tail)
        return sweep
    try:
        doc = json.loads(proc.stdout.strip().splitlines()[-1])
        sweep.rows, sweep.machine = list(doc["rows"]), dict(doc["machine"])
    except (ValueError, KeyError, IndexError) as err:
        sweep.error = f"output is not the bench JSON: {err}"
    return sweep


def main(argv: Sequence[str] | None = None) -> int:
    from bench import heldout, report_page

    parser = argparse.ArgumentParser(prog="python -m bench.report", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="each sweep's --quick size")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "performance.md")
    parser.add_argument("--only", default="", metavar="NAME,NAME", help="these sweeps only")
    parser.add_argument(
        "--heldout-grasps",
        type=int,
        default=None,
        help=f"grasps of the classifier's held-out set (default {heldout.GRASPS}, "
        f"{heldout.QUICK_GRASPS} with --quick; 0 skips it)",
    )
    parser.add_argument(
        "--workdir",
        type=Path,
        default=ROOT / "out" / "report",
        help="where the held-out dataset is written",
    )
    parser.add_argument("--timeout-secs", type=float, default=1800.0, help="per sweep")
    args = parser.parse_args(argv)
    found = discover()
    chosen = [n for n in args.only.split(",") if n] or found
    unknown = sorted(set(chosen) - set(found))
    if unknown:
        parser.error(f"--only: no sweep {unknown}; found: {', '.join(found)}")
    grasps = args.heldout_grasps
    if grasps is None:
        grasps = heldout.QUICK_GRASPS if args.quick else heldout.GRASPS
    if grasps < 0:
        parser.error(f"--heldout-grasps must be >= 0, got {grasps}")
    start = time.perf_counter()
    sweeps = []
    total = len(chosen) + (1 if grasps else 0)
    for index, name in enumerate(chosen, 1):
        print(f"[{index}/{total}] bench.{name} ...", flush=True)
        sweep = run_sweep(name, args.quick, args.timeout_secs)
        status = f"FAILED: {sweep.error}" if sweep.error else f"{len(sweep.rows)} rows"
        print(f"[{index}/{total}] bench.{name}: {sweep.secs:.1f} s, {status}", flush=True)
        sweeps.append(sweep)
    accuracy = None
    if grasps:
        print(f"[{total}/{total}] classifier held-out set ({grasps} grasps) ...", flush=True)
        accuracy = heldout.measure(grasps, workdir=args.workdir, root=ROOT)
        print(f"[{total}/{total}] classifier held-out set: {accuracy.summary()}", flush=True)
    page = report_page.render(
        sweeps,
        accuracy,
        machine=machine(),
        quick=args.quick,
        total_secs=time.perf_counter() - start,
        out=args.out,
        root=ROOT,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(page)
    print(f"wrote {args.out} in {time.perf_counter() - start:.0f} s")
    return 1 if any(s.error for s in sweeps) else 0


if __name__ == "__main__":
    sys.exit(main())
