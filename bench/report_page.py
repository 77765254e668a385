"""The page ``bench.report`` writes: tables, Pareto plots, the default graph's settings.

:data:`PARETO` says, per sweep with an accuracy knob, which columns are the time and the
error, which rows to plot and how to name a point. A point is on the Pareto front when no
other point of the sweep is both faster and at least as accurate. The default graph's
setting is found by matching its node's implementation and parameters against the rows'
columns (``graph.yaml``; ``graphs/sort.yaml`` for the classifier, which the default graph
does not run), so the page says where the default sits, measured, not remembered.
"""

from __future__ import annotations

import datetime
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import yaml

from bench.common import Row

if TYPE_CHECKING:
    from bench.heldout import HeldOut


@dataclass
class Sweep:
    """One sweep's result: its rows, how long it took, the command, what went wrong."""

    name: str
    command: str
    rows: list[Row] = field(default_factory=list)
    machine: dict[str, Any] = field(default_factory=dict)
    secs: float = 0.0
    error: str = ""
    columns: list[str] | None = None


@dataclass(frozen=True)
class Pareto:
    """How to plot one sweep's error against time."""

    time: str
    error: str
    label: Callable[[Row], str]
    group: str
    keep: Callable[[Row], bool] = lambda row: True
    error_of: Callable[[Row], float] | None = None  # derived error (e.g. 1 - accuracy)
    error_label: str = ""
    time_label: str = ""
    graph: str = "graph.yaml"
    impl_prefix: str = ""
    # The row columns (and values) the default node's implementation and parameters (its
    # Params dataclass, defaults filled in) correspond to.
    want: Callable[[str, dict[str, Any]], dict[str, Any]] = lambda impl, params: {}
    # Rows with a cost but no error (the simulator's effect sets): drawn as bars of
    # ``time`` per ``bars`` label instead.
    bars: str = ""
    bars_keep: Callable[[Row], bool] = lambda row: False
    # A caveat the rows call for, or "".
    note: Callable[[Sequence[Row]], str] = lambda rows: ""
    # Whether the rows' errors mean anything: when not (a classifier trained on a toy set
    # where the real datasets are missing), the section draws no plot and no front, and
    # says why; the times stand in the table.
    errors_mean: Callable[[Sequence[Row]], bool] = lambda rows: True


PARETO: dict[str, Pareto] = {
    "pose": Pareto(
        time="solve_ms_median",
        error="axis_err_deg_median",
        label=lambda r: f"{r['solver']} {r['points']} pts {r['tol']} {r['start']} ({r['source']})",
        group="solver",
        keep=lambda r: r.get("kind") == "accuracy",
        error_label="axis error, median (deg)",
        time_label="solve time, median (ms)",
        impl_prefix="pose_estimator.",
        # bench.pose's "tight" is tol 1e-8 ("loose" 1e-4); tracking starts each fit warm.
        want=lambda impl, p: {
            "solver": impl.removeprefix("pose_estimator."),
            "tol": "tight" if p.get("tol", p.get("cost_tol", 1e-8)) <= 1e-6 else "loose",
            "start": "warm" if p.get("track") else "cold",
        },
    ),
    "shear": Pareto(
        time="ms_per_frame_median",
        error="dir_err_deg_median",
        label=lambda r: str(r["setting"]),
        group="method",
        error_label="direction error, median (deg)",
        time_label="CPU time per frame, median (ms)",
        impl_prefix="shear_tracker.",
        want=lambda impl, p: {
            "method": impl.removeprefix("shear_tracker."),
            "scale": p["scale"],
            "warm_start": p["warm_start"],
        },
    ),
    "classifier": Pareto(
        time="infer_ms_median",
        error="error",
        error_of=lambda r: 1.0 - float(r["accuracy"]),
        label=lambda r: f"{r['modality']} {r['input_px']} px w{r['width']}",
        group="modality",
        error_label="frame error (1 - accuracy)",
        time_label="inference, median (ms, batch 1)",
        graph="graphs/sort.yaml",
        impl_prefix="classifier.",
        want=lambda impl, p: _checkpoint_knobs(p["model"], p["modality"]),
        note=lambda rows: (
            "These rows are trained and scored on bench.classifier's toy dataset (the "
            "auto-labelled datasets it sweeps on, CLASSIFIER_TRAIN and CLASSIFIER_TEST, are "
            "not on this machine): their times hold, their accuracies say nothing of the "
            "task, so no error is plotted. The shipped model's accuracy on real auto-labelled "
            "grasps is the held-out section below."
            if any(r.get("data") == "toy" for r in rows)
            else ""
        ),
        errors_mean=lambda rows: not any(r.get("data") == "toy" for r in rows),
    ),
    "sim": Pareto(
        time="ms_per_frame",
        error="depth_rms_mm",
        label=lambda r: f"1/{r['resolution_divisor']} res, {r['march_steps']} steps",
        group="resolution_divisor",
        keep=lambda r: r.get("sweep") == "membrane",
        error_label="depth error against the finest membrane, RMS (mm)",
        time_label="both bubbles' render, median (ms per frame)",
        bars="effects",
        bars_keep=lambda r: r.get("sweep") == "effects",
    ),
}


def _checkpoint_knobs(model: str, modality: str) -> dict[str, Any]:
    """The sweep's columns for the classifier node's checkpoint (its size and width)."""
    from perception.classify.checkpoint import load_checkpoint

    path = Path(__file__).resolve().parents[1] / model
    if not path.is_file():
        return {}
    _, meta = load_checkpoint(path)
    return {"modality": modality, "input_px": meta.input_px, "width": meta.width}


def _error(spec: Pareto, row: Row) -> float:
    return float(spec.error_of(row) if spec.error_of else row[spec.error])


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats in both time and error (finite ones)."""
    front = []
    for i, (t, e) in enumerate(points):
        if not (math.isfinite(t) and math.isfinite(e)):
            continue
        beaten = any(
            (t2 <= t and e2 <= e) and (t2 < t or e2 < e)
            for j, (t2, e2) in enumerate(points)
            if j != i and math.isfinite(t2) and math.isfinite(e2)
        )
        if not beaten:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    return str(value).replace("|", "/")


def markdown_table(rows: Sequence[Row], columns: Sequence[str] | None = None) -> str:
    """A Markdown table of ``rows`` (floats to 4 significant digits)."""
    if not rows:
        return "(no rows)"
    cols = [c for c in (columns or list(rows[0])) if any(c in r for r in rows)]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_cell(r.get(c, "")) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def default_node(spec: Pareto, root: Path) -> tuple[str, dict[str, Any]] | None:
    """``(impl, params)`` of the default graph's node for this sweep (params with the
    node's defaults filled in), or None."""
    path = root / spec.graph
    if not spec.impl_prefix or not path.is_file():
        return None
    doc = yaml.safe_load(path.read_text()) or {}
    for body in (doc.get("nodes") or {}).values():
        impl = str(body.get("impl", ""))
        if impl.startswith(spec.impl_prefix):
            given = dict(body.get("params") or {})
            import nodes
            from runtime.registry import resolve

            nodes.import_all()
            params = resolve(impl).Params(**given)
            full = msgspec.structs.asdict(params)
            return impl, {"given": given, "full": full}
    return None


def default_rows(name: str, spec: Pareto, rows: Sequence[Row], root: Path) -> tuple[str, list[int]]:
    """A sentence naming the default setting, and the indices of the rows that match it."""
    if name == "sim":
        return _sim_default(rows, root)
    node = default_node(spec, root)
    if node is None:
        return "", []
    impl, params = node
    want = spec.want(impl, params["full"])
    matched = [
        i
        for i, row in enumerate(rows)
        if spec.keep(row) and want and all(row.get(k) == v for k, v in want.items())
    ]
    shown = ", ".join(f"{k}: {v}" for k, v in params["given"].items()) or "its defaults"
    columns = ", ".join(f"{k} = {v}" for k, v in want.items())
    return f"`{spec.graph}` runs `{impl}` with {shown} ({columns} in this table)", matched


def _sim_default(rows: Sequence[Row], root: Path) -> tuple[str, list[int]]:
    """The default graph's scene: its effects, membrane resolution and march steps."""
    import sim

    doc = yaml.safe_load((root / "graph.yaml").read_text())
    scene_path = next(
        (b["params"]["scene"] for b in doc["nodes"].values() if b.get("impl") == "world.sim"),
        None,
    )
    if scene_path is None:
        return "", []
    scene = sim.load_scene(root / scene_path)
    knobs = {
        "resolution_divisor": scene.membrane.resolution_divisor,
        "march_steps": scene.membrane.march_steps,
    }
    matched = [
        i
        for i, r in enumerate(rows)
        if r.get("sweep") == "membrane" and all(r.get(k) == v for k, v in knobs.items())
    ]
    shown = ", ".join(f"{k} = {v}" for k, v in knobs.items())
    effects = ", ".join(scene.effects)
    return f"`graph.yaml`'s scene `{scene_path}` simulates {effects} with {shown}", matched


def plot_pareto(
    name: str, spec: Pareto, rows: Sequence[Row], defaults: list[int], path: Path
) -> None:
    """Error against time, one colour per group, the front as a line, defaults circled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = [i for i, r in enumerate(rows) if spec.keep(r)]
    points = [(float(rows[i][spec.time]), _error(spec, rows[i])) for i in kept]
    front = pareto_front(points)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    groups = sorted({str(rows[i][spec.group]) for i in kept})
    for g_index, group in enumerate(groups):
        xs = [p[0] for k, p in zip(kept, points, strict=True) if str(rows[k][spec.group]) == group]
        ys = [p[1] for k, p in zip(kept, points, strict=True) if str(rows[k][spec.group]) == group]
        ax.scatter(xs, ys, s=18, color=f"C{g_index}", label=f"{spec.group} {group}")
    ax.plot(
        [points[i][0] for i in front],
        [points[i][1] for i in front],
        "k--",
        lw=0.8,
        label="Pareto front",
    )
    for k, (t, e) in zip(kept, points, strict=True):
        if k in defaults:
            ax.scatter([t], [e], s=120, facecolors="none", edgecolors="red", linewidths=1.2)
    if any(i in defaults for i in kept):
        ax.scatter([], [], s=120, facecolors="none", edgecolors="red", label="default graph")
    positive = [p for p in points if p[0] > 0 and p[1] > 0]
    if positive and max(p[0] for p in positive) / min(p[0] for p in positive) > 20:
        ax.set_xscale("log")
    if positive and max(p[1] for p in positive) / min(p[1] for p in positive) > 20:
        ax.set_yscale("log")
    ax.set_xlabel(spec.time_label or spec.time)
    ax.set_ylabel(spec.error_label or spec.error)
    ax.set_title(f"{name}: error against time")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_bars(name: str, spec: Pareto, rows: Sequence[Row], path: Path) -> None:
    """The cost of each row that has no error (``spec.bars`` labels, ``spec.time`` values)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = [r for r in rows if spec.bars_keep(r)]
    fig, ax = plt.subplots(figsize=(6.4, 0.35 * len(kept) + 1.2))
    ax.barh([str(r[spec.bars]) for r in kept], [float(r[spec.time]) for r in kept], color="C0")
    ax.invert_yaxis()
    ax.set_xlabel(spec.time_label or spec.time)
    ax.set_title(f"{name}: cost of each {spec.bars} set")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _pareto_section(sweep: Sweep, spec: Pareto, out: Path, root: Path) -> list[str]:
    kept = [i for i, r in enumerate(sweep.rows) if spec.keep(r)]
    if not kept or any(spec.time not in sweep.rows[i] for i in kept):
        return [f"No rows to plot error against time for `{sweep.name}`."]
    sentence, defaults = default_rows(sweep.name, spec, sweep.rows, root)
    image = out.parent / "img" / "performance" / f"{sweep.name}_pareto.png"
    if not spec.errors_mean(sweep.rows):
        image.unlink(missing_ok=True)  # an old plot must not stay beside this run's table
        lines = [spec.note(sweep.rows), ""]
        if sentence and defaults:
            where = [
                f"{spec.label(sweep.rows[i])}: {_cell(float(sweep.rows[i][spec.time]))} {spec.time}"
                for i in defaults
            ]
            lines += [f"Default: {sentence}. Measured here: " + "; ".join(where) + ".", ""]
        return lines
    plot_pareto(sweep.name, spec, sweep.rows, defaults, image)
    points = [(float(sweep.rows[i][spec.time]), _error(spec, sweep.rows[i])) for i in kept]
    front = [kept[i] for i in pareto_front(points)]
    rel = image.relative_to(out.parent).as_posix()
    lines = [f"![{sweep.name}: error against time]({rel})", ""]
    if spec.note(sweep.rows):
        lines += [spec.note(sweep.rows), ""]
    if any(spec.bars_keep(r) for r in sweep.rows):
        bars = image.with_name(f"{sweep.name}_{spec.bars}.png")
        plot_bars(sweep.name, spec, sweep.rows, bars)
        lines += [
            f"![{sweep.name}: cost per {spec.bars} set]({bars.relative_to(out.parent).as_posix()})",
            "",
        ]
    lines.append(
        "Pareto front (fastest first): "
        + "; ".join(
            f"{spec.label(sweep.rows[i])} ({_cell(float(sweep.rows[i][spec.time]))} / "
            f"{_cell(_error(spec, sweep.rows[i]))})"
            for i in front
        )
        + f", as ({spec.time} / {spec.error})."
    )
    lines.append("")
    if sentence:
        if defaults:
            where = [
                f"{spec.label(sweep.rows[i])}: {_cell(float(sweep.rows[i][spec.time]))} "
                f"{spec.time}, {_cell(_error(spec, sweep.rows[i]))} {spec.error}"
                + (" (on the front)" if i in front else " (off the front)")
                for i in defaults
            ]
            lines.append(f"Default: {sentence}. Measured here: " + "; ".join(where) + ".")
        else:
            lines.append(f"Default: {sentence}; no row of this run matches it.")
        lines.append("")
    return lines


def render(
    sweeps: Sequence[Sweep],
    accuracy: HeldOut | None,
    *,
    machine: dict[str, Any],
    quick: bool,
    total_secs: float,
    out: Path,
    root: Path,
) -> str:
    """The whole page as Markdown (plots written next to it under ``img/performance``)."""
    size = "--quick" if quick else "full"
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Performance: what accuracy costs in time",
        "",
        f"Written by `python -m bench.report{' --quick' if quick else ''}` on {date} "
        f"({size} sizes, {total_secs / 60:.1f} min in all). Each section's command reruns its sweep "
        "alone and prints the same table (`--json` for the rows, `--plot PATH` for its own plot).",
        "",
        "## Machine",
        "",
        markdown_table([machine]),
        "",
    ]
    for sweep in sweeps:
        lines += [f"## {sweep.name}", "", "```text", sweep.command, "```", ""]
        if sweep.error:
            lines += [f"This sweep failed in this run: {sweep.error}", ""]
            continue
        lines += [f"{len(sweep.rows)} rows in {sweep.secs:.0f} s.", ""]
        lines += [markdown_table(sweep.rows, sweep.columns), ""]
        spec = PARETO.get(sweep.name)
        if spec is not None:
            lines += _pareto_section(sweep, spec, out, root)
    lines += ["## Tactile classifier on a fresh held-out set", ""]
    if accuracy is None:
        lines += ["Not measured in this run (`--heldout-grasps 0`).", ""]
    else:
        lo, hi = accuracy.interval
        lines += [
            f"The committed model scored on {accuracy.grasps} grasps ({accuracy.frames} frames, "
            f"classes {', '.join(accuracy.classes)}) that the report made itself: "
            f"**{100 * accuracy.accuracy:.2f}%** of grasps right (the majority of a grasp's "
            f"frames), 95% Wilson interval {100 * lo:.2f}% to {100 * hi:.2f}%; "
            f"{100 * accuracy.frame_accuracy:.2f}% of frames. Made and scored in "
            f"{accuracy.secs / 60:.1f} min with:",
            "",
            "```text",
            accuracy.make_command,
            accuracy.score_command,
            "```",
            "",
        ]
    return "\n".join(lines)
