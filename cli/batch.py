"""``launch.py batch replay|autolabel``: many recordings, or many worlds, as tasks on Ray.

python launch.py batch replay 'runs/*.mcap' --out DIR [--swap NODE[=IMPL] ...] [--set ...]
                              [--lockstep] [--address ADDR | --workers N | --no-ray]
python launch.py batch autolabel --seeds 1-8 --grasps 50 --out DIR [--graph G]
                                 [--address ADDR | --workers N | --no-ray]

Each recording (each world) is one task; a task runs the same command a user would
(``cli.batchjobs``). Without ``--address`` a local Ray is started for the command and
stopped after it (nothing to set up); ``--address`` joins a running cluster (``auto``, or
``ray://HOST:10001``). ``--no-ray`` runs the same tasks one after another in this
process: the baseline the batch is measured against (bench/batch.py). See docs/batch.md.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cli import batchjobs

Job = Callable[..., dict[str, Any]]


def parse_seeds(text: str) -> list[int]:
    """``1-4,7`` -> ``[1, 2, 3, 4, 7]`` (ranges inclusive, order kept, no repeats)."""
    seeds: list[int] = []
    for part in text.split(","):
        first, sep, last = part.strip().partition("-")
        try:
            low, high = int(first), int(last) if sep else int(first)
        except ValueError:
            raise SystemExit(f"--seeds {text!r}: expected numbers and ranges like 1-4,7") from None
        if high < low or high - low > 100_000:
            raise SystemExit(f"--seeds {text!r}: range {part!r} is empty or too long")
        seeds += [s for s in range(low, high + 1) if s not in seeds]
    return seeds


def run_tasks(
    job: Job,
    calls: Sequence[tuple[Any, ...]],
    names: Sequence[str],
    *,
    address: str | None,
    workers: int,
    use_ray: bool,
) -> list[dict[str, Any]]:
    """Run ``job(*call)`` for each call, on Ray unless ``use_ray`` is false; print a line
    as each ends; return the rows in the calls' order."""
    rows: list[dict[str, Any] | None] = [None] * len(calls)
    start = time.monotonic()

    def report(index: int, row: dict[str, Any]) -> None:
        rows[index] = row
        done = sum(r is not None for r in rows)
        state = "skipped (done before)" if row.get("skipped") else row.get("status", "?")
        reason = f": {row['reason']}" if row.get("status") == "failed" else ""
        print(
            f"[{done}/{len(calls)} {time.monotonic() - start:.0f}s] {names[index]}: {state}"
            f" {row.get('secs', 0):.1f}s{reason}",
            file=sys.stderr,
            flush=True,
        )

    if not use_ray:
        for index, call in enumerate(calls):
            report(index, job(*call))
        return [r for r in rows if r is not None]
    try:
        import ray
    except ImportError:
        raise SystemExit(
            "batch: Ray is not installed (pip install 'ray==2.60.0'), or use --no-ray"
        ) from None
    if address:
        ray.init(address=address, logging_level="WARNING", log_to_driver=False)
    else:
        ray.init(
            num_cpus=workers or os.cpu_count() or 1,
            include_dashboard=False,
            logging_level="WARNING",
            log_to_driver=False,
            # Rows are small; the recordings move as files, never through the store.
            object_store_memory=80 * 1024 * 1024,
        )
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(job)
        pending = {remote.remote(*call): index for index, call in enumerate(calls)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                index = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except Exception as err:  # a worker lost: that task failed, not the batch
                    row = {"status": "failed", "reason": f"task lost: {type(err).__name__}: {err}"}
                report(index, row)
    finally:
        ray.shutdown()
    return [r for r in rows if r is not None]


def _poses(row: dict[str, Any]) -> str:
    return " ".join(f"{k}:{v}" for k, v in row.get("poses", {}).items()) or "-"


def replay_table(rows: Sequence[dict[str, Any]]) -> str:
    """Per recording and in total: messages, poses by status, outcome, differences."""
    head = f"{'recording':<28} {'status':<8} {'secs':>7} {'messages':>9} {'differences':>11}  poses / outcome"
    lines = [head]
    total: dict[str, Any] = {"messages": 0, "differences": 0, "poses": {}, "secs": 0.0}
    for row in rows:
        diffs = sum(row.get("differences", {}).values())
        name = Path(row.get("recording", "?")).name
        lines.append(
            f"{name:<28} {row.get('status', '?'):<8} {row.get('secs', 0):>7.1f}"
            f" {row.get('messages', 0):>9} {diffs:>11}  {_poses(row)}"
            + (f" / {row['outcome']}" if row.get("outcome") else "")
            + (f"  ({row['reason']})" if row.get("status") == "failed" else "")
        )
        total["messages"] += row.get("messages", 0)
        total["differences"] += diffs
        total["secs"] += row.get("secs", 0)
        for status, count in row.get("poses", {}).items():
            total["poses"][status] = total["poses"].get(status, 0) + count
    failed = sum(r.get("status") != "ok" for r in rows)
    lines.append(
        f"{f'total ({len(rows)}, {failed} failed)':<28} {'':<8} {total['secs']:>7.1f}"
        f" {total['messages']:>9} {total['differences']:>11}  {_poses(total)}"
    )
    return "\n".join(lines)


def batch_replay(args: argparse.Namespace) -> int:
    bags = sorted(glob.glob(args.pattern))
    if not bags:
        print(f"batch replay: no recording matches {args.pattern!r}", file=sys.stderr)
        return 2
    stems = [Path(b).stem for b in bags]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        print(
            f"batch replay: two recordings named {twice[0]!r}: outputs would collide",
            file=sys.stderr,
        )
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    calls = [
        (str(Path(b).resolve()), str(out.resolve()), args.swaps, args.sets, args.lockstep)
        for b in bags
    ]
    rows = run_tasks(
        batchjobs.replay_job,
        calls,
        stems,
        address=args.address,
        workers=args.workers,
        use_ray=not args.no_ray,
    )
    print(replay_table(rows))
    (out / "batch.json").write_text(json.dumps(rows, indent=1, sort_keys=True))
    return 0 if all(r.get("status") == "ok" for r in rows) else 1


def batch_autolabel(args: argparse.Namespace) -> int:
    seeds = parse_seeds(args.seeds)
    out = Path(args.out).resolve()
    parts = [out / "parts" / f"seed_{seed:06d}" for seed in seeds]
    calls = [
        (str(Path(args.graph).resolve()), seed, args.grasps, str(part))
        for seed, part in zip(seeds, parts, strict=True)
    ]
    rows = run_tasks(
        batchjobs.autolabel_job,
        calls,
        [f"seed {s}" for s in seeds],
        address=args.address,
        workers=args.workers,
        use_ray=not args.no_ray,
    )
    print(f"{'seed':>8} {'status':<8} {'grasps':>7} {'secs':>8} {'grasps/min':>10}")
    for seed, row in zip(seeds, rows, strict=True):
        grasps, secs = row.get("grasps", 0), row.get("secs", 0.0)
        rate = 60 * grasps / secs if secs else 0.0
        print(f"{seed:>8} {row['status']:<8} {grasps:>7} {secs:>8.1f} {rate:>10.2f}")
    if not all(r["status"] == "ok" for r in rows):
        print(
            "batch autolabel: a world failed; nothing merged (rerun to finish it)", file=sys.stderr
        )
        return 1
    from perception.classify.dataset import merge_datasets

    dataset = out / "dataset"
    staging = out / "dataset.partial"
    shutil.rmtree(staging, ignore_errors=True)
    manifest = merge_datasets(parts, staging)
    shutil.rmtree(dataset, ignore_errors=True)
    os.replace(staging, dataset)
    print(f"{dataset}: {len(manifest['grasps'])} grasps of {len(parts)} worlds, one manifest")
    return 0


def main(args: argparse.Namespace) -> int:
    """``launch.py batch ...``: the exit code (1 when any task failed)."""
    if args.batch_command == "replay":
        return batch_replay(args)
    return batch_autolabel(args)


def add_parser(commands: Any) -> None:
    """``batch replay`` and ``batch autolabel`` in the command tree (``cli.main``)."""
    from cli.options import add_graph_changes

    parser = commands.add_parser(
        "batch",
        help="replay many bags, or auto-label many worlds, as tasks on Ray (docs/batch.md)",
        description="Many recordings or many simulated worlds, each its own task on Ray.",
    )
    sub = parser.add_subparsers(dest="batch_command", metavar="COMMAND", required=True)
    replay = sub.add_parser("replay", help="replay every recording a pattern matches")
    replay.add_argument("pattern", help="a glob of recordings, quoted: 'runs/*.mcap'")
    replay.add_argument("--out", required=True, help="folder of the outputs and batch.json")
    add_graph_changes(
        replay, swap_metavar="NODE[=IMPL]", swap_help="run NODE live, with IMPL if given"
    )
    replay.add_argument("--lockstep", action="store_true", help="each replay in lockstep")
    label = sub.add_parser("autolabel", help="the auto-labelling graph as N worlds, one dataset")
    label.add_argument("--seeds", required=True, help="one world per seed: 1-8 or 1,2,5")
    label.add_argument("--grasps", type=int, required=True, help="grasps per world")
    label.add_argument("--out", required=True, help="parts/ per world and the merged dataset/")
    label.add_argument("--graph", default=str(batchjobs.ROOT / "graphs" / "autolabel.yaml"))
    for each in (replay, label):
        where = each.add_mutually_exclusive_group()
        where.add_argument(
            "--address", default=None, help="a running Ray cluster (auto, ray://HOST:10001)"
        )
        where.add_argument(
            "--workers", type=int, default=0, help="local Ray: tasks at once (default: CPUs)"
        )
        where.add_argument(
            "--no-ray", action="store_true", help="one task after another, in this process"
        )
        each.set_defaults(handler="cli.batch")
