"""A picture of a graph file: its nodes and their topics, as Graphviz DOT or Mermaid text.

Takes plain data (``cli.graphdraw`` builds it from the checked graph): a box per node
labelled with its name and implementation, an arrow per edge labelled with the topic and
its message type (an input's port when it differs from the output's name). Graphviz's
``dot`` renders DOT to SVG or PNG where it is installed; Mermaid text renders in GitHub
and GitLab Markdown (a ```mermaid block) and in the Mermaid live editor.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Edge:
    topic: str
    type_name: str
    publisher: str
    subscriber: str
    port: str


def _label(topic: str, type_name: str, port: str) -> str:
    output = topic.split("/", 1)[-1]
    via = f" -> {port}" if port != output else ""
    return f"{topic}{via}\\n{type_name}"


def _quote(text: str) -> str:
    return '"' + text.replace('"', '\\"') + '"'


def to_dot(nodes: dict[str, str], edges: list[Edge], title: str = "") -> str:
    """DOT text: ``nodes`` maps a node's name to its implementation."""
    lines = [
        "digraph graph_file {",
        "  rankdir=LR;",
        '  node [shape=box, style="rounded,filled", fillcolor="#eef3fb", fontname="Helvetica"];',
        '  edge [fontname="Helvetica", fontsize=9];',
    ]
    if title:
        lines.append(f"  label={_quote(title)}; labelloc=t;")
    for name, impl in nodes.items():
        label = _quote(name + "\\n" + impl)
        lines.append(f"  {_quote(name)} [label={label}];")
    for e in edges:
        label = _label(e.topic, e.type_name, e.port)
        lines.append(f"  {_quote(e.publisher)} -> {_quote(e.subscriber)} [label={_quote(label)}];")
    lines.append("}")
    return "\n".join(lines) + "\n"


def _mermaid_id(name: str) -> str:
    return "n_" + re.sub(r"\W", "_", name)


def to_mermaid(nodes: dict[str, str], edges: list[Edge]) -> str:
    """Mermaid flowchart text (``flowchart LR``)."""
    lines = ["flowchart LR"]
    for name, impl in nodes.items():
        lines.append(f'  {_mermaid_id(name)}["{name}<br/><small>{impl}</small>"]')
    for e in edges:
        label = _label(e.topic, e.type_name, e.port).replace("\\n", "<br/>")
        lines.append(f'  {_mermaid_id(e.publisher)} -->|"{label}"| {_mermaid_id(e.subscriber)}')
    return "\n".join(lines) + "\n"


def draw(nodes: dict[str, str], edges: list[Edge], out: Path, title: str = "") -> tuple[Path, str]:
    """Write the picture to ``out`` by its suffix: ``.svg``/``.png``/``.pdf`` with Graphviz's
    ``dot``, ``.dot``/``.gv`` DOT text, ``.mmd``/``.md`` Mermaid text (``.md`` inside a
    fenced block). Returns the file written and a note: without ``dot`` an image is not
    drawn; DOT and Mermaid text are written beside it instead and the note says so."""
    suffix = out.suffix.lower()
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix in (".dot", ".gv"):
        out.write_text(to_dot(nodes, edges, title))
        return out, ""
    if suffix in (".mmd", ".md"):
        text = to_mermaid(nodes, edges)
        out.write_text(f"```mermaid\n{text}```\n" if suffix == ".md" else text)
        return out, ""
    if suffix not in (".svg", ".png", ".pdf"):
        raise ValueError(f"{out}: draw to .svg, .png, .pdf (Graphviz), .dot, .gv, .mmd or .md")
    dot = shutil.which("dot")
    if dot is None:
        text_out = out.with_suffix(".dot")
        text_out.write_text(to_dot(nodes, edges, title))
        out.with_suffix(".mmd").write_text(to_mermaid(nodes, edges))
        return text_out, (
            f"Graphviz's `dot` is not installed, so {out} was not drawn: wrote DOT text to "
            f"{text_out} and Mermaid text to {out.with_suffix('.mmd')} (install graphviz, or "
            "paste the Mermaid text into a ```mermaid block)"
        )
    subprocess.run(
        [dot, f"-T{suffix[1:]}", "-o", str(out)],
        input=to_dot(nodes, edges, title),
        text=True,
        check=True,
        capture_output=True,
        timeout=60,
    )
    return out, ""
