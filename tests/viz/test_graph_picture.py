"""``launch.py graph GRAPH --draw OUT``: DOT and Mermaid text of the checked graph, and an
SVG where Graphviz's ``dot`` is installed."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

import launch
import nodes  # noqa: F401 - the index of node implementations
from runtime.graph import check, load_document

ROOT = Path(__file__).resolve().parents[2]


def checked_edges() -> set[tuple[str, str]]:
    graph = check(load_document(ROOT / "graph.yaml"))
    providers = graph.providers()
    return {(providers[topic][0], node) for topic, node, _ in graph.edges()}


def test_dot_text_has_every_node_and_edge(tmp_path: Path) -> None:
    out = tmp_path / "g.dot"
    assert launch.main(["graph", "graph.yaml", "--draw", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("digraph")
    drawn = set(re.findall(r'^  "(\w+)" -> "(\w+)"', text, re.M))
    assert drawn == checked_edges()
    assert '"pose" [label="pose\\npose_estimator.ipopt"]' in text
    assert 'label="contact_patch/patch -> patch\\nContactPatch"' not in text  # same name
    assert 'label="contact_patch/patch\\nContactPatch"' in text


def test_mermaid_text_in_markdown(tmp_path: Path) -> None:
    out = tmp_path / "g.md"
    argv = ["graph", "graph.yaml", "--draw", str(out), "--swap", "pose=pose_estimator.icp"]
    assert launch.main(argv) == 0
    text = out.read_text()
    assert text.startswith("```mermaid\nflowchart LR\n") and text.endswith("```\n")
    assert "pose_estimator.icp" in text
    arrows = re.findall(r"^  n_(\w+) -->\|.*\| n_(\w+)$", text, re.M)
    assert set(arrows) == checked_edges()


def test_an_image_without_graphviz_writes_text_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(shutil, "which", lambda name: None)
    out = tmp_path / "g.svg"
    assert launch.main(["graph", "graph.yaml", "--draw", str(out)]) == 0
    assert not out.exists()
    assert (tmp_path / "g.dot").read_text().startswith("digraph")
    assert (tmp_path / "g.mmd").read_text().startswith("flowchart LR")
    assert "`dot` is not installed" in capsys.readouterr().err


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz's dot is not installed")
def test_svg_with_graphviz(tmp_path: Path) -> None:
    out = tmp_path / "g.svg"
    assert launch.main(["graph", "graph.yaml", "--draw", str(out)]) == 0
    text = out.read_text()
    assert "<svg" in text and "pose_estimator.ipopt" in text


def test_a_bad_graph_draws_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "g.dot"
    argv = ["graph", "graph.yaml", "--draw", str(out), "--swap", "pose=nope"]
    assert launch.main(argv) == 2
    assert not out.exists() and "graph check failed" in capsys.readouterr().err
