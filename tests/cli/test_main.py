"""The command line: subcommands in --help, `nodes [IMPL]`, one vocabulary for run and replay,
dotted --set, and errors that name the file, the node and the field."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

import launch
from cli.main import parser
from cli.nodes import node_details, node_table
from tests.runtime.test_bagtool import make_bag

NESTED = "tests.runtime.nodes_for_tests:NestedNode"


def test_help_lists_every_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        launch.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    _, names = parser()
    assert names[0] == "run" and {"nodes", "bag", "replay", "keys"} <= set(names)
    commands = {line.split()[0] for line in out.splitlines() if re.match(r"    \S", line)}
    assert commands == set(names)
    assert "`python launch.py GRAPH ...` runs a graph" in out
    bag = _help_of(["bag"])
    for command in ("info", "echo", "diff", "recover", "view", "export", "video"):
        assert f"    {command}" in bag
    run = _help_of(["run"])
    assert "--record-topics" in run and "--swap" in run and "--topics" not in run


def test_nodes_marks_optional_inputs(capsys: pytest.CaptureFixture[str]) -> None:
    assert launch.main(["nodes"]) == 0
    out = capsys.readouterr().out
    (sink,) = [line for line in out.splitlines() if line.startswith("synthetic.sink ")]
    assert "in: tick:Tick, [other]:Tick" in sink
    assert "[port]: an optional input" in out
    assert "recorder" in node_table(["recorder"]) and "any topic" in node_table(["recorder"])


def test_nodes_impl_shows_params_with_defaults_units_and_limits(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert launch.main(["nodes", "synthetic.source"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.strip()]
    (rate,) = [row for row in rows if row[0] == "rate_hz"]
    assert rate == ["rate_hz", "float", "20.0", "Hz", ">", "0"]
    (count,) = [row for row in rows if row[0] == "count"]
    assert "  rate_hz: ticks per second" in out  # the declared description
    assert count == ["count", "int", "100", "-", ">=", "0"]
    text = node_details(NESTED)
    assert "inputs:  tick:Tick" in text
    (winsize,) = [line for line in text.splitlines() if line.strip().startswith("inner.winsize")]
    assert "15" in winsize and "in [3, 201]" in winsize
    (model,) = [line for line in text.splitlines() if line.strip().startswith("model ")]
    assert "path of an existing file" in model
    assert "  tol: a solver tolerance." in text
    # The docstring's first paragraph, whole, even where it wraps over several lines.
    summary = node_details("pose_estimator.ipopt").splitlines()[1]
    assert summary.endswith("or loaded from the per-user disk cache).")


def test_nodes_with_an_unknown_impl_lists_the_valid_ones(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert launch.main(["nodes", "no.such"]) == 2
    err = capsys.readouterr().err
    assert "unknown implementation 'no.such'" in err and "synthetic.source" in err


def test_run_and_replay_share_one_vocabulary() -> None:
    run = parser()[0].parse_args(
        ["run", "g.yaml", "--swap", "a=b", "--set", "a.b.c=1", "--record", "o.mcap"]
        + ["--record-topics", "x/.*"]
    )
    assert (run.swaps, run.sets, run.record_topics) == (["a=b"], ["a.b.c=1"], "x/.*")
    replay_help = _help_of(["replay"])
    for flag in ("--swap", "--set", "--record", "--record-topics", "--replay-topics"):
        assert flag in replay_help
    assert "--replace" not in replay_help and "--topics " not in replay_help


def _help_of(command: list[str]) -> str:
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        launch.main([*command, "--help"])
    return out.getvalue()


def test_old_spellings_still_work_and_say_what_replaced_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = parser()[0].parse_args(["run", "g.yaml", "--topics", "x/.*"])
    assert run.record_topics == "x/.*"
    assert "warning: --topics is deprecated; use --record-topics" in capsys.readouterr().err
    bag = make_bag(tmp_path / "a.mcap")
    chosen = ["--replay-topics", "source_a/.*", "--print-graph"]
    assert launch.main(["replay", str(bag), "--swap", "relay", *chosen]) == 0
    new = capsys.readouterr().out
    assert "source_b:" in new  # not replayed: its node runs live
    assert (
        launch.main(
            ["replay", str(bag), "--replace", "relay", "--topics", "source_a/.*", "--print-graph"]
        )
        == 0
    )
    captured = capsys.readouterr()
    assert captured.out == new
    assert "--replace is deprecated; use --swap" in captured.err
    assert "--topics is deprecated; use --replay-topics" in captured.err


def test_replay_topics_chooses_what_the_bag_plays(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = make_bag(tmp_path / "a.mcap")
    assert (
        launch.main(["replay", str(bag), "--replay-topics", "^source_b/tick$", "--print-graph"])
        == 0
    )
    graph = yaml.safe_load(capsys.readouterr().out)
    assert set(graph["nodes"]) == {"replay"}
    assert graph["nodes"]["replay"]["params"]["topics"] == "^(?:source_b/tick)$"


def test_check_with_a_dotted_set(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(
        f"nodes:\n  src: {{impl: synthetic.source}}\n  n: {{impl: '{NESTED}', inputs: {{tick: src/tick}}}}\n"
    )
    assert launch.main([str(path), "--check", "--set", "n.inner.winsize=45"]) == 0
    assert "OK, 2 nodes, 1 edges" in capsys.readouterr().out
    assert launch.main([str(path), "--check", "--set", "n.inner.winsize=2"]) == 2
    err = capsys.readouterr().err
    assert f"{path}: node 'n'.params.inner.winsize: must be in [3, 201], got 2" in err


BAD_GRAPHS = {
    "unknown impl": "  a: {impl: no.such}\n",
    "bad param": "  a: {impl: synthetic.source, params: {rate_hz: -1}}\n",
    "wrong type": "  a: {impl: synthetic.source, params: {count: 1.5}}\n",
    "unknown param": "  a: {impl: synthetic.source, params: {colour: red}}\n",
    "nan": "  a: {impl: synthetic.source, params: {rate_hz: .nan}}\n",
    "hang nan": "  a: {impl: synthetic.source, hang_timeout_secs: .nan}\n",
    "bad host": "  a: {impl: synthetic.source, host: 'nowhere.invalid'}\n",
    "queue size": "  a: {impl: synthetic.source}\n"
    "  b: {impl: synthetic.sink, inputs: {tick: {from: a/tick, queue_size: 0}}}\n",
    "unconnected": "  b: {impl: synthetic.sink}\n",
    "no producer": "  b: {impl: synthetic.sink, inputs: {tick: ghost/tick}}\n",
    "restart": "  a: {impl: synthetic.source, restart: {max_restarts: -1}}\n",
    "missing file": f"  a: {{impl: synthetic.source}}\n  n: {{impl: '{NESTED}', "
    "params: {model: nowhere.pt}, inputs: {tick: a/tick}}\n",
    "unknown key": "  a: {impl: synthetic.source, colour: red}\n",
}


@pytest.mark.parametrize("case", sorted(BAD_GRAPHS))
def test_every_error_names_the_file_the_node_and_the_field(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("nodes:\n" + BAD_GRAPHS[case])
    assert launch.main([str(path), "--check"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "graph check failed:"
    assert lines[1:], case
    for line in lines[1:]:
        assert line.startswith(f"{path}: node '"), line
        node_and_field = line.split(": ")[1]
        assert "'." in node_and_field or "unknown key" in line, line


def test_replay_in_a_fresh_process_knows_the_registered_implementations(tmp_path: Path) -> None:
    """A fresh ``launch.py replay`` resolves registered names (it imports the node index
    itself, as ``run`` does; in-process tests above import it through the suite)."""
    import subprocess
    import sys

    bag = make_bag(tmp_path / "a.mcap", topics=("contact_patch/patch",))
    root = Path(launch.__file__).parent
    command = [sys.executable, str(root / "launch.py"), "replay", str(bag)]
    command += ["--graph", str(root / "graph.yaml"), "--swap", "pose=pose_estimator.lm"]
    done = subprocess.run(
        [*command, "--print-graph"], capture_output=True, text=True, timeout=120, cwd=root
    )
    assert done.returncode == 0, done.stderr
    assert "pose_estimator.lm" in done.stdout
