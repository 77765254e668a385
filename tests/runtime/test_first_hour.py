"""The first hour's stumbles: a graph run from elsewhere, a failed export's stub, a
negative duration, the bag help, a mistyped implementation."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import launch
import nodes  # noqa: F401 - the index of node implementations (anchor_paths resolves them)

ROOT = Path(__file__).resolve().parents[2]


def run_from(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, str(ROOT / "launch.py"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize("graph", ["graph.yaml", "graphs/sort.yaml"])
def test_a_graph_checks_from_any_working_directory(graph: str, tmp_path: Path) -> None:
    proc = run_from(tmp_path, str(ROOT / graph), "--check")
    assert proc.returncode == 0, proc.stderr
    assert "OK" in proc.stdout


def test_scene_paths_are_found_from_the_graph_file(tmp_path: Path) -> None:
    from runtime.graph import check, load_document

    (tmp_path / "scenes").mkdir()
    scene = tmp_path / "scenes" / "mine.yaml"
    scene.write_text((ROOT / "scenes" / "handover_task.yaml").read_text())
    (tmp_path / "graphs").mkdir()
    graph = tmp_path / "graphs" / "g.yaml"
    graph.write_text("nodes:\n  world: {impl: world.sim, params: {scene: scenes/mine.yaml}}\n")
    doc = load_document(graph)
    assert doc["nodes"]["world"]["params"]["scene"] == str(scene.resolve())
    check(doc, source=str(graph))
    graph.write_text("nodes:\n  world: {impl: world.sim, params: {scene: scenes/none.yaml}}\n")
    assert load_document(graph)["nodes"]["world"]["params"]["scene"] == "scenes/none.yaml"


@pytest.mark.parametrize(
    ("command", "option", "name"),
    [("view", "--out", "x.rrd"), ("export", "--foxglove", "x.mcap"), ("video", "--out", "x.mp4")],
)
def test_a_failed_bag_command_leaves_no_stub(
    command: str, option: str, name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not a bag at all")
    out = tmp_path / name
    assert launch.main(["bag", command, str(bad), option, str(out)]) == 2
    assert str(bad) in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]
    out.write_bytes(b"an earlier output")
    assert launch.main(["bag", command, str(bad), option, str(out)]) == 2
    assert out.read_bytes() == b"an earlier output"


@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "soon"])
@pytest.mark.parametrize("command", [["graph.yaml"], ["replay", "x.mcap"]])
def test_a_duration_must_be_positive(
    command: list[str], value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        launch.main([*command, "--duration", value])
    assert stop.value.code == 2
    assert f"--duration: must be a number of seconds > 0, got '{value}'" in capsys.readouterr().err


def test_bag_help_lists_every_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        launch.main(["bag", "--help"])
    text = capsys.readouterr().out
    for name in ("info", "echo", "diff", "recover", "view", "export", "video"):
        assert f"    {name} " in text, name


def test_a_mistyped_implementation_gets_a_suggestion(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["graph.yaml", "--swap", "pose=pose_estimator.ipoptt", "--check"]
    assert launch.main(argv) == 2
    err = capsys.readouterr().err
    assert "did you mean pose_estimator.ipopt" in err
    assert "bubble_camera.royale" not in err  # not the whole list
    assert launch.main(["graph.yaml", "--swap", "pose=zzzz", "--check"]) == 2
    assert "valid: " in capsys.readouterr().err  # nothing close: the list
