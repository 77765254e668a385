"""The work of one batch task: one recording replayed, or one world auto-labelled.

Each job runs the project's own command line in a child process (``launch.py replay``,
``launch.py GRAPH``), exactly what a user would type, so a batch output is the output of
a single run by construction. A job never raises for a bad recording or a crashed graph:
it returns a row with ``status: failed`` and the reason, so a batch goes on.

The functions here know nothing of Ray (``cli.batch`` submits them): they run the same
in a plain loop, in a local Ray, or on a cluster's workers, where the project and its
venv must be installed at the same path (docs/batch.md).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / "launch.py"
DONE_SUFFIX = ".json"  # a replay's row, written once its output is complete
PASSES = 3  # runs of one world's auto-labelling graph to make all its grasps


# The launcher's own lines that say why a run failed (runtime.launcher): a node that failed
# or died, a start-up that timed out. Its end-of-run table follows them, so the last line
# of the output says nothing of the cause.
WHY = ("failed", "died", "timed out", "refused", "error")


def failure_reason(output: str, log: Path | None = None) -> str:
    """Why a child ``launch.py`` failed, from its output: the launcher's lines that say so
    (else the output's last line), and where the whole output was kept."""
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    said = [
        ln
        for ln in lines
        if ln.startswith("[launch] ")
        and not ln.startswith("[launch] stopping:")
        and any(w in ln for w in WHY)
    ]
    # A failed node's own last line (its error) follows what the launcher said of it.
    named = {m.group(1) for ln in said if (m := re.search(r"node '([\w.-]+)'", ln))}
    own = [next((ln for ln in reversed(lines) if ln.startswith(f"[{n}] ")), "") for n in named]
    reason = "; ".join([*said[:3], *sorted(filter(None, own))]) or (
        lines[-1] if lines else "(no output)"
    )
    return f"{reason} (output: {log})" if log is not None else reason


def _keep_output(child: subprocess.CompletedProcess[str], log: Path) -> str:
    """Append a child's output to ``log`` (a failure is inspected there); return it."""
    output = child.stdout + child.stderr
    with log.open("a") as f:
        f.write(f"$ {' '.join(map(str, child.args))}\n# exit {child.returncode}\n{output}\n")
    return output


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def replay_command(
    bag: Path, out: Path, swaps: list[str], sets: list[str], lockstep: bool
) -> list[str]:
    """The ``launch.py replay`` command line of one recording (what a user would type)."""
    command = [sys.executable, str(LAUNCH), "replay", str(bag), "--record", str(out)]
    command += ["--overwrite", "--log-level", "WARNING"]
    for swap in swaps:
        command += ["--swap", swap]
    for item in sets:
        command += ["--set", item]
    if lockstep:
        command.append("--lockstep")
    return command


def summarize(path: Path) -> dict[str, Any]:
    """Messages in all, poses by status, and the task events of one recording."""
    from runtime.bag import BagReader

    with BagReader(path) as reader:
        types = {topic: schema.type_name for topic, schema in reader.topics().items()}
        stats = reader.stats()
        wanted = [t for t, name in types.items() if name in ("PoseEstimate", "TaskEvent")]
        poses: Counter[str] = Counter()
        events: Counter[str] = Counter()
        outcome = ""
        for message in reader.messages(wanted):
            value = message.decode_plain()
            if types[message.topic] == "PoseEstimate":
                poses[str(value.get("status", "?"))] += 1
            else:
                events[str(value.get("event", "?"))] += 1
                if value.get("event") in ("summary", "succeeded", "failed", "released"):
                    outcome = str(value.get("event"))
    return {
        "messages": int(sum(s.messages for s in stats.values())),
        "poses": dict(sorted(poses.items())),
        "events": dict(sorted(events.items())),
        "outcome": outcome,
    }


def differences(original: Path, out: Path) -> dict[str, int]:
    """Per topic, how many differences ``bag diff`` finds between a recording and its
    replay (topics the replay reran differ where the changed node answers otherwise)."""
    from runtime.bag.diff import diff_bags

    per_topic: Counter[str] = Counter(d.topic for d in diff_bags(original, out))
    return dict(sorted(per_topic.items()))


def replay_job(
    bag: str, out_dir: str, swaps: list[str], sets: list[str], lockstep: bool
) -> dict[str, Any]:
    """Replay one recording into ``out_dir/<stem>.mcap`` and return its row.

    A row already in ``out_dir`` for the same recording and options is returned as it
    is (``skipped``): a rerun does only what is missing or failed.
    """
    source = Path(bag)
    out = Path(out_dir) / f"{source.stem}.mcap"
    done = out.with_suffix(DONE_SUFFIX)
    options = {"swaps": swaps, "sets": sets, "lockstep": lockstep}
    row: dict[str, Any] = {"recording": str(source), "output": str(out), **options}
    if done.is_file() and out.is_file():
        previous = json.loads(done.read_text())
        if previous.get("status") == "ok" and all(previous.get(k) == v for k, v in options.items()):
            return {**previous, "skipped": True}
    partial = out.with_name(out.stem + ".partial")
    start = time.monotonic()
    child = subprocess.run(
        replay_command(source, partial, swaps, sets, lockstep),
        capture_output=True,
        text=True,
        cwd=ROOT,
        stdin=subprocess.DEVNULL,
    )
    row["secs"] = round(time.monotonic() - start, 3)
    if child.returncode != 0 or not partial.is_file():
        partial.unlink(missing_ok=True)
        log = out.with_suffix(".log")
        reason = failure_reason(_keep_output(child, log), log)
        return {**row, "status": "failed", "exit": child.returncode, "reason": reason}
    os.replace(partial, out)
    try:
        row.update(summarize(out))
        row["differences"] = differences(source, out)
    except Exception as err:  # a damaged output is a failed row, not a failed batch
        return {**row, "status": "failed", "exit": 0, "reason": f"{out}: {err}"}
    row["status"] = "ok"
    _write_atomically(done, json.dumps(row, indent=1, sort_keys=True))
    return row


def autolabel_command(graph: Path, seed: int, grasps: int, part: Path) -> list[str]:
    """The auto-labelling graph of one world: its own seed, its own dataset folder."""
    command = [sys.executable, str(LAUNCH), str(graph), "--log-level", "WARNING"]
    for item in (
        f"world.seed={seed}",
        f"supervisor.seed={seed}",
        f"supervisor.grasps={grasps}",
        f"supervisor.dataset={part}",
        f"writer.dataset={part}",
    ):
        command += ["--set", item]
    return command


def autolabel_job(graph: str, seed: int, grasps: int, part_dir: str) -> dict[str, Any]:
    """Run one world's auto-labelling graph until its dataset holds ``grasps`` grasps.

    The graph resumes from its manifest and draws grasp ``i`` of a seed the same way
    every time, so a grasp that a loaded machine lost (no stable frame pair reached the
    writer) is made again by the next pass, at most ``PASSES`` in all: the world's
    grasps and their parameters depend on the seed only.
    """
    from perception.classify.dataset import DatasetError, read_manifest

    part = Path(part_dir)
    row: dict[str, Any] = {"seed": seed, "part": str(part), "passes": 0}
    start = time.monotonic()
    kept = 0
    while row["passes"] < PASSES and kept < grasps:
        row["passes"] += 1
        child = subprocess.run(
            autolabel_command(Path(graph), seed, grasps, part),
            capture_output=True,
            text=True,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
        )
        try:
            kept = len(read_manifest(part)["grasps"])
        except DatasetError as err:
            row["reason"] = str(err)
        if child.returncode != 0:
            part.mkdir(parents=True, exist_ok=True)
            log = part / "launch.log"
            row["reason"] = failure_reason(_keep_output(child, log), log)
            break
    row["secs"] = round(time.monotonic() - start, 3)
    row["grasps"] = kept
    if kept < grasps and "reason" not in row:
        row["reason"] = f"{kept} of {grasps} grasps after {row['passes']} passes"
    row["status"] = "ok" if kept == grasps and "reason" not in row else "failed"
    return row
