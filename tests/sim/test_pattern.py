"""The dot pattern generator and its stencil CLI (paper, Printed Patterning)."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from sim.pattern import generate, main, texture, to_svg

KW = dict(
    density_per_mm2=0.08, min_diameter_mm=1.0, max_diameter_mm=2.0, width_mm=80.0, height_mm=120.0
)


@pytest.mark.parametrize("randomness", [0.0, 0.5, 1.0])
def test_density_diameters_and_no_overlap(randomness: float) -> None:
    pat = generate(randomness=randomness, seed=4, **KW)
    n = len(pat.diameters_mm)
    assert n / (80 * 120) == pytest.approx(0.08, rel=0.2)
    assert pat.diameters_mm.min() >= 1.0 and pat.diameters_mm.max() <= 2.0
    d = np.linalg.norm(pat.centers_mm[:, None] - pat.centers_mm[None], axis=-1)
    limit = (pat.diameters_mm[:, None] + pat.diameters_mm[None]) / 2
    np.fill_diagonal(d, np.inf)
    assert np.all(d >= limit)
    r = pat.diameters_mm / 2
    assert np.all(pat.centers_mm - r[:, None] >= 0)
    assert np.all(pat.centers_mm[:, 0] + r <= 80) and np.all(pat.centers_mm[:, 1] + r <= 120)


def test_randomness_zero_is_a_lattice_and_seed_is_deterministic() -> None:
    lattice = generate(randomness=0.0, seed=1, **KW)
    rows = np.unique(np.round(lattice.centers_mm[:, 1], 6))
    assert len(rows) < 40  # dots share rows exactly
    a = generate(randomness=0.8, seed=9, **KW)
    b = generate(randomness=0.8, seed=9, **KW)
    c = generate(randomness=0.8, seed=10, **KW)
    np.testing.assert_array_equal(a.centers_mm, b.centers_mm)
    assert a.centers_mm.shape != c.centers_mm.shape or not np.array_equal(
        a.centers_mm, c.centers_mm
    )


def test_bad_parameters_name_the_field() -> None:
    with pytest.raises(ValueError, match="randomness"):
        generate(randomness=1.5, seed=0, **KW)
    with pytest.raises(ValueError, match="min_diameter_mm"):
        generate(**{**KW, "min_diameter_mm": 5.0, "max_diameter_mm": 6.0}, randomness=0.1, seed=0)


def test_svg_circles_match_the_pattern(tmp_path: Path) -> None:
    pat = generate(randomness=0.7, seed=2, **KW)
    root = ET.fromstring(to_svg(pat))
    circles = [e for e in root.iter() if e.tag.endswith("circle")]
    assert len(circles) == len(pat.diameters_mm)
    assert float(circles[0].get("r")) == pytest.approx(pat.diameters_mm[0] / 2, abs=1e-3)
    assert root.get("width") == "80.000mm"


CLI_ARGS = (
    *("--density", "0.05", "--min-diameter-mm", "1", "--max-diameter-mm", "2.5"),
    *("--randomness", "0.6", "--seed", "3"),
)


def test_cli_writes_the_stencil(tmp_path: Path) -> None:
    out = tmp_path / "stencil.svg"
    cmd = [sys.executable, "-m", "sim.pattern", *CLI_ARGS, "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert out.read_text().count("<circle") > 100
    assert main([*CLI_ARGS, "--out", str(tmp_path / "b.svg")]) == 0
    assert (tmp_path / "b.svg").read_text() == out.read_text()


def test_texture_shows_the_same_dots() -> None:
    kw = dict(
        density_per_mm2=0.05,
        min_diameter_mm=1.5,
        max_diameter_mm=2.0,
        randomness=0.5,
        seed=5,
        width_mm=40.0,
        height_mm=30.0,
    )
    pat = generate(**kw)
    tex = texture(**kw, mm_per_px=0.1, dot_albedo=0.25)
    assert tex.shape == (300, 400)
    cols = np.clip((pat.centers_mm[:, 0] / 0.1).astype(int), 0, 399)
    rows = np.clip((pat.centers_mm[:, 1] / 0.1).astype(int), 0, 299)
    np.testing.assert_allclose(tex[rows, cols], 0.25, atol=0.05)
    ink_fraction = (tex < 0.625).mean()
    expected = np.sum(np.pi * (pat.diameters_mm / 2) ** 2) / (40 * 30)
    assert ink_fraction == pytest.approx(expected, rel=0.1)


DENSE = dict(min_diameter_mm=0.5, max_diameter_mm=1.5, width_mm=80.0, height_mm=120.0)


def test_dense_pattern_reaches_the_density_asked_without_merging_holes() -> None:
    """0.5 dots/mm^2 of 0.5-1.5 mm dots: the jittered lattice alone drops about half of
    them (0.28 dots/mm^2); placing dots where they fit reaches the density asked."""
    pat = generate(density_per_mm2=0.5, randomness=0.8, seed=0, **DENSE)
    assert pat.density_per_mm2 == pytest.approx(0.5, rel=1e-3)
    assert pat.requested_density_per_mm2 == 0.5
    assert pat.diameters_mm.min() >= 0.5 and pat.diameters_mm.max() <= 1.5
    gap = 0.2 - 1e-9
    centers, radii = pat.centers_mm, pat.diameters_mm / 2
    for i in range(0, len(centers), 7):  # every 7th dot against all: enough, and quick
        d = np.hypot(*(centers - centers[i]).T)
        d[i] = np.inf
        assert np.all(d >= radii + radii[i] + gap)


def test_unreachable_density_is_reported_with_the_knob_to_change(tmp_path: Path) -> None:
    args = ["--density", "0.9", "--min-diameter-mm", "0.8", "--max-diameter-mm", "1.0"]
    out = tmp_path / "dense.svg"
    cmd = [sys.executable, "-W", "error::RuntimeWarning", "-m", "sim.pattern", *args]
    done = subprocess.run(
        [*cmd, "--randomness", "0.8", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert "density not reached" in done.stderr and "(0.9 asked)" in done.stdout
    assert "--max-diameter-mm" in done.stderr
    assert "RuntimeWarning" not in done.stderr
    assert out.read_text().count("<circle") > 4000  # what fits is still written
