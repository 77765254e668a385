"""The JSON Schema of graph files (``launch.py schema``): every shipped graph fits it, and
it refuses what the parameter declarations refuse."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

import launch
from messages.files import load_yaml

jsonschema = pytest.importorskip("jsonschema", reason="the schema is checked with jsonschema")

ROOT = Path(__file__).resolve().parents[2]
GRAPHS = sorted((ROOT / "graphs").glob("*.yaml")) + [ROOT / "graph.yaml"]


@pytest.fixture(scope="module")
def validator() -> Any:
    import nodes
    from runtime.graphschema import graph_schema
    from runtime.registry import known, resolve

    nodes.import_all()
    schema = graph_schema({name: resolve(name) for name in known()})
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def test_the_command_prints_a_valid_schema(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert launch.main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    jsonschema.Draft202012Validator.check_schema(schema)
    assert launch.main(["schema", "--out", str(tmp_path / "s.json")]) == 0
    assert json.loads((tmp_path / "s.json").read_text()) == schema
    assert "contact_patch" in schema["$defs"]["node"]["properties"]["impl"]["anyOf"][0]["enum"]


@pytest.mark.parametrize("path", GRAPHS, ids=lambda p: p.name)
def test_every_shipped_graph_fits_the_schema(validator: Any, path: Path) -> None:
    errors = [
        f"{list(e.absolute_path)}: {e.message}"
        for e in validator.iter_errors(load_yaml(path.read_text()))
    ]
    assert errors == []


@pytest.mark.parametrize(
    "node, where",
    [
        ("{impl: contact_patch, params: {contact: {threshold: 1}}}", "threshold"),
        ("{impl: contact_patch, params: {contact: {max_points: 0}}}", "max_points"),
        ("{impl: contact_patch, params: {reference_frames: 2.5}}", "reference_frames"),
        ("{impl: shear_tracker.farneback, params: {farneback: {poly_n: 6}}}", "poly_n"),
        ("{impl: shear_tracker.farneback, params: {method: dis}}", "method"),
        ("{impl: contact_patch, restart: {policy: always}}", "policy"),
        ("{impl: contact_patch, inputs: {left: {from: a/b, policy: newest}}}", "policy"),
        ("{impl: contact_patch, colour: red}", "colour"),
    ],
)
def test_the_schema_refuses_what_the_declarations_refuse(
    validator: Any, node: str, where: str
) -> None:
    doc = yaml.safe_load(f"nodes:\n  n: {node}\n")
    errors = list(validator.iter_errors(doc))
    assert errors, node
    # the error names the field: in its path, or (an unknown key) in its message
    text = " ".join(f"{list(e.absolute_path)} {e.message}" for e in errors)
    text += " ".join(f"{list(c.absolute_path)} {c.message}" for e in errors for c in e.context)
    assert where in text, text
