"""``launch.py batch``: many recordings replayed on a local Ray, each output the one a
single ``launch.py replay`` gives; a corrupt recording reported while the others go on;
a rerun skips what is done; worlds auto-labelled in parallel merge into one dataset
that does not depend on how many processes made it."""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import pytest

from cli.batch import parse_seeds, replay_table
from cli.batchjobs import autolabel_job
from perception.classify.dataset import DatasetError, load_samples, merge_datasets, read_manifest
from perception.classify.preprocess import InputSpec
from perception.classify.synthetic import write_toy_dataset
from runtime.bag.diff import diff_bags
from tests.launching import launch_py

ROOT = Path(__file__).resolve().parents[2]
SWAP = ["--swap", "pose=pose_estimator.lm", "--lockstep"]


_run = functools.partial(launch_py, timeout=600)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three recordings of the default graph (three lengths), and a corrupt fourth."""
    folder = tmp_path_factory.mktemp("runs")
    for name, secs in (("a", "1"), ("b", "1.5"), ("c", "2")):
        done = _run("graph.yaml", "--duration", secs, "--record", str(folder / f"{name}.mcap"))
        assert done.returncode == 0, done.stderr
    (folder / "d.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 64)
    return folder


@pytest.mark.timeout(900)  # about 2 minutes on a quiet 2-core machine: 10 graphs run
def test_batch_replay_equals_single_replays_and_reports_the_corrupt_one(
    runs: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    batch = _run(
        "batch", "replay", str(runs / "*.mcap"), "--out", str(out), "--workers", "2", *SWAP
    )
    assert batch.returncode == 1, batch.stderr  # one recording failed, the batch did not
    table = batch.stdout
    assert "total (4, 1 failed)" in table, table
    rows = {Path(r["recording"]).stem: r for r in json.loads((out / "batch.json").read_text())}
    assert sorted(rows) == ["a", "b", "c", "d"]
    assert rows["d"]["status"] == "failed" and "d.mcap" in rows["d"]["reason"]
    for name in "abc":
        row = rows[name]
        assert row["status"] == "ok", row
        assert sum(row["poses"].values()) > 0 and row["messages"] > 0
        single = tmp_path / f"single-{name}.mcap"
        done = _run("replay", str(runs / f"{name}.mcap"), *SWAP, "--record", str(single))
        assert done.returncode == 0, done.stderr
        assert diff_bags(single, out / f"{name}.mcap") == []
    # A rerun does only what is not done: the three are skipped, the corrupt one fails again.
    again = _run("batch", "replay", str(runs / "*.mcap"), "--out", str(out), "--no-ray", *SWAP)
    assert again.returncode == 1
    assert again.stderr.count("skipped (done before)") == 3, again.stderr
    # Other options are another batch: nothing is skipped.
    other = _run(
        "batch",
        "replay",
        str(runs / "a.mcap"),
        "--out",
        str(out),
        "--no-ray",
        "--swap",
        "pose=pose_estimator.icp",
        "--lockstep",
    )
    assert other.returncode == 0 and "skipped" not in other.stderr, other.stderr


@pytest.mark.timeout(900)
def test_batch_autolabel_is_the_same_dataset_from_one_process_or_many(tmp_path: Path) -> None:
    made = {}
    for how in (["--no-ray"], ["--workers", "2"]):
        out = tmp_path / how[0].strip("-")
        done = _run(
            "batch", "autolabel", "--seeds", "3-4", "--grasps", "2", "--out", str(out), *how
        )
        assert done.returncode == 0, done.stderr
        made[how[0]] = read_manifest(out / "dataset")
    one, many = made.values()
    # The same grasps, objects and parameters in the same order; the frames' noise is
    # drawn live (docs/batch.md), so the frame files are not compared.
    same = ("grasp_id", "object_class", "params", "source")
    assert [{k: g[k] for k in same} for g in one["grasps"]] == [
        {k: g[k] for k in same} for g in many["grasps"]
    ]
    assert len(one["grasps"]) == 4 and all(g["frames"] > 0 for g in many["grasps"])
    assert [g["source"]["seeds"] for g in one["grasps"]] == [{"autolabel": s} for s in (3, 3, 4, 4)]


def test_a_world_that_fails_says_why_and_keeps_its_output(tmp_path: Path) -> None:
    # A part left by another run (other classes): the writer cannot resume it and fails.
    # The launcher's end-of-run table comes last in its output; the reason must be the
    # launcher's line and the failed node's own, not the table's last row.
    part = write_toy_dataset(tmp_path / "part", classes=("mug", "bowl"), grasps_per_class=1)
    row = autolabel_job(str(ROOT / "graphs" / "autolabel.yaml"), 5, 3, str(part))
    assert row["status"] == "failed" and row["passes"] == 1, row
    assert "required node 'writer' failed" in row["reason"], row["reason"]
    assert "cannot resume, manifest classes" in row["reason"], row["reason"]
    log = part / "launch.log"
    assert str(log) in row["reason"]
    assert "# exit 1" in log.read_text() and "[launch] node " in log.read_text()


def test_merge_numbers_grasps_part_after_part_and_refuses_mixed_classes(tmp_path: Path) -> None:
    first = write_toy_dataset(tmp_path / "p1", grasps_per_class=1, seed=1)
    second = write_toy_dataset(tmp_path / "p2", grasps_per_class=2, seed=2)
    merged = merge_datasets([first, second], tmp_path / "all")
    assert [g["grasp_id"] for g in merged["grasps"]] == list(range(12))
    assert [g["source"]["part"] for g in merged["grasps"]] == [0] * 4 + [1] * 8
    spec = InputSpec(modality="depth", input_px=32)
    whole = load_samples(tmp_path / "all", spec)
    assert len(whole.labels) == len(load_samples(first, spec).labels) + len(
        load_samples(second, spec).labels
    )
    with pytest.raises(DatasetError, match="exists"):
        merge_datasets([first], tmp_path / "all")
    other = write_toy_dataset(tmp_path / "p3", classes=("mug", "bowl"), seed=3)
    with pytest.raises(DatasetError, match="classes"):
        merge_datasets([first, other], tmp_path / "mixed")


def test_seed_lists_and_the_table() -> None:
    assert parse_seeds("1-4,7,2") == [1, 2, 3, 4, 7]
    with pytest.raises(SystemExit, match="--seeds"):
        parse_seeds("4-1")
    with pytest.raises(SystemExit, match="--seeds"):
        parse_seeds("x")
    table = replay_table(
        [
            {
                "recording": "r/a.mcap",
                "status": "ok",
                "secs": 2.0,
                "messages": 10,
                "poses": {"ok": 3},
                "differences": {"pose/pose": 2},
            },
            {"recording": "r/b.mcap", "status": "failed", "secs": 0.1, "reason": "bad"},
        ]
    )
    assert "total (2, 1 failed)" in table and "ok:3" in table and "(bad)" in table


def test_distributed_training_matches_one_process(tmp_path: Path) -> None:
    """``torchrun --nproc-per-node 2`` trains the same checkpoint format to the same
    held-out accuracy as one process, within the interval of the validation set."""
    data = write_toy_dataset(tmp_path / "toy", grasps_per_class=12, frames_per_grasp=4, seed=0)
    common = ["train", str(data), "--epochs", "12", "--input-px", "32", "--width", "0.125"]
    common += ["--batch-size", "16", "--threads", "1"]
    torchrun = [sys.executable, "-m", "torch.distributed.run"]
    accuracy = {}
    for name, launcher in (
        ("one", [sys.executable]),
        ("two", [*torchrun, "--standalone", "--nproc-per-node", "2"]),
    ):
        out = tmp_path / f"{name}.pt"
        done = subprocess.run(
            [*launcher, "-m", "perception.classify", *common, "--out", str(out)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr
        from perception.classify.checkpoint import load_checkpoint

        _, meta = load_checkpoint(out)
        assert meta.training["processes"] == (1 if name == "one" else 2)
        accuracy[name] = meta.training["final"]["val_accuracy"]
    # 64 validation frames (16 grasps): a 95% interval of about +-0.2 around 0.6.
    assert accuracy["one"] > 0.5 and accuracy["two"] > 0.5, accuracy
    assert abs(accuracy["one"] - accuracy["two"]) < 0.25, accuracy
