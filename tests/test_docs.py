"""Every command in a fenced ``sh`` block of README.md and docs/*.md runs, at small sizes.

How a block is run:

* The commands of one Markdown file run in order (a later block may use what an earlier
  one wrote, e.g. a recorded bag) in a scratch directory of their own that links every
  top-level entry of the repository, so relative paths work as in the repository and
  what the commands write stays out of it. Files run side by side, and commands that
  neither write nor read files (graph checks, ``launch.py nodes``) run in parallel. A ``\\`` at the end of a line continues the
  command; ``#`` starts a comment (shell rules, via :mod:`shlex`).
* ``python`` and ``.venv/bin/python`` are the interpreter running the tests.
* Sizes are cut by rule (:func:`small`), never by editing the docs:
  ``launch.py GRAPH`` with ``--record`` runs for ``RECORD_SECS`` (its ``--duration``
  lowered or added); a ``launch.py GRAPH`` run without ``--record`` is checked
  (``--check``: the arguments, ``--set``, ``--swap``, ``--only`` and the whole graph)
  instead of started, because starting a full graph costs half a minute on a loaded
  machine and ``tests/test_graphs.py`` already runs the shipped graphs end to end;
  ``python -m bench.NAME`` gets ``--quick``.
* A command passes when it exits 0 without a traceback. ``launch.py bag diff`` exits 1
  when it found differences, which is its documented result, so 1 passes for it too. A
  command the docs end with ``|| true`` shows an error on purpose: any exit code passes,
  a traceback does not.
* A block that cannot run here is preceded by an HTML comment
  ``<!-- docs-test: skip REASON -->`` (invisible when rendered). The reason is required;
  such blocks must stay rare (building the virtual environment, running this suite).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RECORD_SECS = "2"
COMMAND_TIMEOUT_SECS = 240
FENCE = re.compile(r"^```(\S*)\s*$")
MARKER = re.compile(r"^<!--\s*docs-test:\s*(\S+)\s*(.*?)\s*-->\s*$")
SHOWS_AN_ERROR = ("||", "true")  # a documented command that fails on purpose ends so


@dataclass(frozen=True)
class Block:
    """One fenced ``sh`` block: where it is, its commands, and why it is skipped."""

    path: Path
    line: int
    commands: tuple[tuple[str, ...], ...]
    skip_reason: str = ""


def split_commands(text: str, where: str) -> list[tuple[str, ...]]:
    """The commands of a block: continuation lines joined, comments and blanks dropped."""
    joined = re.sub(r"\\\n", " ", text)
    out = []
    for line in joined.splitlines():
        try:
            argv = shlex.split(line, comments=True)
        except ValueError as err:
            raise ValueError(f"{where}: cannot parse {line!r}: {err}") from err
        if argv:
            out.append(tuple(argv))
    return out


def parse_blocks(path: Path, text: str | None = None) -> list[Block]:
    """Every ``sh`` block of a Markdown file, with its ``docs-test`` marker if any."""
    lines = (path.read_text() if text is None else text).splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        fence = FENCE.match(lines[i])
        if not fence:
            i += 1
            continue
        end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), None)
        if end is None:
            raise ValueError(f"{path.name}:{i + 1}: unclosed code fence")
        if fence.group(1) == "sh":
            where = f"{path.name}:{i + 1}"
            before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
            marker = MARKER.match(before.strip())
            reason = ""
            if marker:
                if marker.group(1) != "skip":
                    raise ValueError(f"{where}: unknown docs-test marker {marker.group(1)!r}")
                reason = marker.group(2)
                if not reason:
                    raise ValueError(f"{where}: `docs-test: skip` needs a reason")
            commands = tuple(split_commands("\n".join(lines[i + 1 : end]), where))
            blocks.append(Block(path, i + 1, commands, reason))
        i = end + 1
    return blocks


def _set_option(argv: list[str], option: str, value: str) -> list[str]:
    if option in argv:
        k = argv.index(option)
        return [*argv[: k + 1], value, *argv[k + 2 :]]
    return [*argv, option, value]


def small(argv: tuple[str, ...]) -> list[str]:
    """The command as the test runs it (see the module docstring for the rules)."""
    out = list(argv)
    tail: list[str] = []
    if tuple(out[-2:]) == SHOWS_AN_ERROR:
        out, tail = out[:-2], out[-2:]
    if out[0] in ("python", "python3", ".venv/bin/python"):
        out[0] = sys.executable
    if len(out) > 2 and out[1] == "launch.py" and out[2].endswith((".yaml", ".yml")):
        if "--record" in out:
            out = _set_option(out, "--duration", RECORD_SECS)
        elif "--check" not in out:
            out.append("--check")
    elif len(out) > 2 and out[1] == "-m" and out[2].startswith("bench.") and "--quick" not in out:
        out.append("--quick")
    return out + tail


def allowed_exit_codes(argv: list[str]) -> set[int] | None:
    """The exit codes that pass; None: any, as long as it does not crash."""
    if tuple(argv[-2:]) == SHOWS_AN_ERROR:
        return None
    if argv[1:4] == ["launch.py", "bag", "diff"]:
        return {0, 1}  # 1: differences found, the documented result
    return {0}


def scratch(work: Path) -> Path:
    """A directory that looks like the repository root but keeps what commands write."""
    work.mkdir(parents=True)
    for entry in ROOT.iterdir():
        if entry.name.startswith(".") or entry.name in ("runs", "out"):
            continue
        (work / entry.name).symlink_to(entry)
    return work


def is_pure(command: list[str], written: set[str] | frozenset[str] = frozenset()) -> bool:
    """A command that writes nothing and reads nothing a command before it wrote: a
    graph check or the node listing that names none of ``written`` (see
    :func:`new_names`). These run at once, in parallel."""
    if "--check" not in command and command[1:3] != ["launch.py", "nodes"]:
        return False
    return not any(arg.rpartition("=")[2] in written for arg in command[2:])


def new_names(command: list[str]) -> set[str]:
    """The arguments of a command (the VALUE of a NAME=VALUE one) that are no entry of
    the repository: what it may write (``calibrate --out my_rig.yaml``), so a check
    naming one (``--set camera.calibration=my_rig.yaml``) waits for it."""
    values = {arg.rpartition("=")[2] for arg in command[2:] if not arg.startswith("-")}
    return {v for v in values if v and not (ROOT / v).exists()}


def run_command(path: Path, block: Block, argv: tuple[str, ...], work: Path) -> str:
    """Run one documented command; an empty string when it passed, else the failure."""
    command = small(argv)
    allowed = allowed_exit_codes(command)
    if allowed is None:
        command = command[: -len(SHOWS_AN_ERROR)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["MPLBACKEND"] = "Agg"
    done = subprocess.run(
        command,
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=COMMAND_TIMEOUT_SECS,
    )
    crashed = "Traceback (most recent call last)" in done.stderr + done.stdout
    if (done.returncode in allowed if allowed is not None else True) and not crashed:
        return ""
    return (
        f"{path.name}:{block.line}: {shlex.join(argv)}\nran: {shlex.join(command)}\n"
        f"exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    )


def run_file(path: Path, blocks: list[Block], work: Path, pool: ThreadPoolExecutor) -> list[str]:
    """Pure commands in parallel (each distinct one once), the rest in document order."""
    steps = [(b, argv) for b in blocks if not b.skip_reason for argv in b.commands]
    pure: dict[tuple[str, ...], Future[str]] = {}
    in_order: list[tuple[Block, tuple[str, ...]]] = []
    written: set[str] = set()
    for block, argv in steps:
        command = small(argv)
        if not is_pure(command, written):
            in_order.append((block, argv))
            written |= new_names(command)
        elif tuple(command) not in pure:
            pure[tuple(command)] = pool.submit(run_command, path, block, argv, work)
    failures = [run_command(path, block, argv, work) for block, argv in in_order]
    return [f for f in (*failures, *(f.result() for f in pure.values())) if f]


ALL_BLOCKS = {path: parse_blocks(path) for path in DOCS}


# Each graph start is several seconds of imports; a machine shared by many jobs needs
# more than the suite's default limit.
@pytest.mark.timeout(1200)
def test_documented_commands_run(tmp_path: Path) -> None:
    """Each file's commands in order in a scratch directory of its own; the files side
    by side (most of a command's time is start-up, waiting on imports)."""
    # Two pools: a file's thread waits on its checks, so they must not share workers.
    with ThreadPoolExecutor(max_workers=4) as files, ThreadPoolExecutor(max_workers=4) as checks:
        runs = [
            files.submit(run_file, path, blocks, scratch(tmp_path / path.stem), checks)
            for path, blocks in ALL_BLOCKS.items()
            if any(b.commands and not b.skip_reason for b in blocks)
        ]
        failures = [f for run in runs for f in run.result()]
    assert not failures, "\n\n".join(failures)


def python_blocks(path: Path) -> list[str]:
    """The fenced ``python`` blocks of a Markdown file."""
    return re.findall(r"^```python\n(.*?)^```", path.read_text(), re.S | re.M)


@pytest.mark.parametrize("snippet", python_blocks(ROOT / "docs" / "sim.md"))
def test_library_snippets_run_from_any_directory(snippet: str, tmp_path: Path) -> None:
    """docs/sim.md's library examples, run from a directory outside the project: they
    need the project installed as a package (``pip install -e .``), nothing else."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    installed = subprocess.run(
        [sys.executable, "-c", "import sim"], cwd=tmp_path, env=env, capture_output=True
    )
    if installed.returncode != 0:
        pytest.skip("the project is not installed as a package here (`pip install -e .`)")
    done = subprocess.run(
        [sys.executable, "-c", snippet],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=COMMAND_TIMEOUT_SECS,
    )
    assert done.returncode == 0, done.stderr[-3000:]


def test_blocks_are_parsed_with_shell_rules_and_markers(tmp_path: Path) -> None:
    text = (
        "<!-- docs-test: skip builds the virtual environment -->\n"
        "```sh\nmake run   # the default graph\n```\n\n"
        "```sh\n# a comment\npython launch.py bag diff a.mcap b.mcap \\\n"
        "    --topic 'pose/pose'   # compare\n\n.venv/bin/python -m bench.sim\n```\n"
        "```yaml\nnot: run\n```\n"
    )
    skipped, run = parse_blocks(tmp_path / "x.md", text)
    assert skipped.skip_reason == "builds the virtual environment"
    assert run.commands == (
        ("python", "launch.py", "bag", "diff", "a.mcap", "b.mcap", "--topic", "pose/pose"),
        (".venv/bin/python", "-m", "bench.sim"),
    )
    with pytest.raises(ValueError, match="needs a reason"):
        parse_blocks(tmp_path / "y.md", "<!-- docs-test: skip -->\n```sh\nmake\n```\n")


def test_sizes_are_cut_by_rule() -> None:
    py = sys.executable
    assert small(("python", "launch.py", "graph.yaml", "--duration", "10")) == [
        py,
        "launch.py",
        "graph.yaml",
        "--duration",
        "10",
        "--check",
    ]
    assert small(("python", "launch.py", "graph.yaml", "--record", "a.mcap")) == [
        py,
        "launch.py",
        "graph.yaml",
        "--record",
        "a.mcap",
        "--duration",
        RECORD_SECS,
    ]
    assert small((".venv/bin/python", "-m", "bench.codec", "--json"))[-1] == "--quick"
    assert small(("python", "launch.py", "bag", "info", "a.mcap")) == [
        py,
        "launch.py",
        "bag",
        "info",
        "a.mcap",
    ]


def test_a_command_shown_failing_on_purpose_passes_unless_it_crashes() -> None:
    command = small(("python", "launch.py", "graph.yaml", "--set", "pose.tol=-1", "||", "true"))
    assert command[-2:] == ["||", "true"] and "--check" in command
    assert allowed_exit_codes(command) is None
    assert allowed_exit_codes(small(("python", "launch.py", "nodes"))) == {0}


FIGURES = re.compile(r"<!-- figures: (\S+) -->\n(.*?)<!-- end figures -->", re.S)
NUMBER = re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?![\w.])")


def test_readme_quotes_its_figures_from_the_performance_page() -> None:
    """Every number in the README's figures block is on the page it names, so the
    README's headline figures are copied from a measurement, not remembered."""
    blocks = FIGURES.findall((ROOT / "README.md").read_text())
    assert blocks, "README.md has no <!-- figures: PAGE --> block"
    for page, text in blocks:
        on_page = set(NUMBER.findall((ROOT / page).read_text()))
        quoted = NUMBER.findall(text)
        assert quoted, f"the figures block for {page} quotes no number"
        missing = [n for n in quoted if n not in on_page]
        assert not missing, f"README.md quotes {missing}, which {page} does not say"
