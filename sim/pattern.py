"""The pseudorandom dot pattern printed inside the membrane, and its laser-cut stencil.

The paper (Printed Patterning) generates patterns by script with four knobs: dot density
(dots/mm^2), minimum and maximum dot diameter, and randomness; they are written as
vector files for laser cutting adhesive stencils. This module is that script, and the
simulator textures the membrane with the same dots (``sim.tof``).

Generation: dots start on a hexagonal lattice whose cell area is ``1 / density``; each
moves by a uniform offset of up to ``randomness`` times half the lattice spacing, draws
a diameter uniformly in ``[min, max]``, and is dropped if it would come closer than a
small gap to a dot already kept (the stencil must not merge holes). Randomness 0 gives
the regular lattice; 1 gives a jittered, non-repeating pattern that dense optical flow
can track without aliasing. Dropped dots and the sheet's edges leave the pattern short of
the density asked, so a second pass places dots where they fit: random positions, each
dot as large as its drawn diameter or as the room there allows (never under the
minimum), until the sheet holds ``density * area`` dots or no room is found (not with
randomness 0, which asks for the regular lattice). Where the
density is not reachable (large dots, dense pattern), the pattern says how far it got
(:attr:`DotPattern.density_per_mm2` against :attr:`DotPattern.requested_density_per_mm2`)
and the command line says which knob to change.

Command line::

    python -m sim.pattern --density 0.08 --min-diameter-mm 1 --max-diameter-mm 2 \
        --randomness 0.8 --seed 0 --out stencil.svg [--width-mm 80 --height-mm 120]
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SHORT_FRACTION = 0.01  # the command line reports a pattern this much under the density asked
FILL_ATTEMPTS_PER_DOT = 40  # random positions tried per missing dot before giving up


@dataclass(frozen=True)
class DotPattern:
    """Dots on a sheet: centres (N, 2) mm from the sheet's corner, diameters (N,) mm."""

    width_mm: float
    height_mm: float
    centers_mm: np.ndarray
    diameters_mm: np.ndarray
    requested_density_per_mm2: float

    @property
    def density_per_mm2(self) -> float:
        """The density reached: dots per mm^2 of the sheet."""
        return len(self.diameters_mm) / (self.width_mm * self.height_mm)


def generate(
    *,
    density_per_mm2: float,
    min_diameter_mm: float,
    max_diameter_mm: float,
    randomness: float,
    seed: int,
    width_mm: float,
    height_mm: float,
    min_gap_mm: float = 0.2,
) -> DotPattern:
    """Generate a pattern (see the module docstring); deterministic for a seed.

    Raises:
        ValueError: a non-positive size or density, diameters out of order, randomness
            outside [0, 1], or dots too large for the density (they could not fit).
    """
    for name, value in (
        ("density_per_mm2", density_per_mm2),
        ("min_diameter_mm", min_diameter_mm),
        ("width_mm", width_mm),
        ("height_mm", height_mm),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"`{name}` must be > 0, got {value!r}")
    if not max_diameter_mm >= min_diameter_mm:
        raise ValueError(f"`max_diameter_mm` must be >= min_diameter_mm, got {max_diameter_mm!r}")
    if not 0.0 <= randomness <= 1.0:
        raise ValueError(f"`randomness` must be in [0, 1], got {randomness!r}")
    # Hexagonal lattice: cell area = spacing^2 * sqrt(3) / 2 = 1 / density.
    spacing = math.sqrt(2.0 / (math.sqrt(3.0) * density_per_mm2))
    if min_diameter_mm + min_gap_mm > spacing:
        raise ValueError(
            f"`min_diameter_mm` {min_diameter_mm} does not fit a density of {density_per_mm2}"
            f" dots/mm^2 (lattice spacing {spacing:.3f} mm)"
        )
    row_step = spacing * math.sqrt(3.0) / 2.0
    rows = int(math.ceil(height_mm / row_step)) + 1
    cols = int(math.ceil(width_mm / spacing)) + 1
    jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
    x = jj * spacing + (ii % 2) * spacing / 2.0
    y = ii * row_step
    lattice = np.stack([x.ravel(), y.ravel()], axis=1)
    rng = np.random.default_rng(seed)
    jitter = rng.uniform(-1.0, 1.0, lattice.shape) * (randomness * spacing / 2.0)
    diameters = rng.uniform(min_diameter_mm, max_diameter_mm, len(lattice))
    centers = lattice + jitter
    inside = (
        (centers[:, 0] - diameters / 2 >= 0)
        & (centers[:, 0] + diameters / 2 <= width_mm)
        & (centers[:, 1] - diameters / 2 >= 0)
        & (centers[:, 1] + diameters / 2 <= height_mm)
    )
    centers, diameters = centers[inside], diameters[inside]
    sheet = _Sheet(width_mm, height_mm, min_gap_mm, max(spacing, max_diameter_mm + min_gap_mm))
    for center, diameter in zip(centers, diameters, strict=True):
        if sheet.room_mm(center) >= diameter:
            sheet.add(center, diameter)
    target = round(density_per_mm2 * width_mm * height_mm)
    # A stream of its own: the lattice pass stays the same whatever the fill does.
    fill_rng = np.random.default_rng([seed, 1])
    # Randomness 0 asks for the regular lattice: nothing is placed off it.
    missing = max(target - sheet.count, 0) if randomness > 0 else 0
    attempts = FILL_ATTEMPTS_PER_DOT * missing
    low = np.array([min_diameter_mm / 2] * 2)
    high = np.array([width_mm, height_mm]) - min_diameter_mm / 2
    for center, drawn in zip(
        fill_rng.uniform(low, high, (attempts, 2)),
        fill_rng.uniform(min_diameter_mm, max_diameter_mm, attempts),
        strict=True,
    ):
        if sheet.count >= target:
            break
        room = sheet.room_mm(center)
        if room >= min_diameter_mm:
            sheet.add(center, min(drawn, room))
    return DotPattern(width_mm, height_mm, *sheet.arrays(), density_per_mm2)


class _Sheet:
    """Dots placed so far, on a hash grid: a dot only meets dots in the cells around it."""

    def __init__(self, width_mm: float, height_mm: float, gap_mm: float, cell_mm: float) -> None:
        self.size = (width_mm, height_mm)
        self.gap = gap_mm
        self.cell = cell_mm  # >= the largest dot plus the gap
        self.grid: dict[tuple[int, int], list[int]] = {}
        self.centers: list[tuple[float, float]] = []
        self.diameters: list[float] = []

    @property
    def count(self) -> int:
        return len(self.diameters)

    def room_mm(self, center: np.ndarray) -> float:
        """The largest dot diameter that fits at ``center``: inside the sheet, and a gap
        away from every dot placed."""
        x, y = float(center[0]), float(center[1])
        radius = min(x, y, self.size[0] - x, self.size[1] - y)
        kx, ky = int(x // self.cell), int(y // self.cell)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for j in self.grid.get((kx + dx, ky + dy), ()):
                    cx, cy = self.centers[j]
                    reach = math.hypot(x - cx, y - cy) - self.diameters[j] / 2 - self.gap
                    radius = min(radius, reach)
        return 2.0 * radius

    def add(self, center: np.ndarray, diameter: float) -> None:
        x, y = float(center[0]), float(center[1])
        self.grid.setdefault((int(x // self.cell), int(y // self.cell)), []).append(self.count)
        self.centers.append((x, y))
        self.diameters.append(float(diameter))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.array(self.centers, dtype=np.float64).reshape(-1, 2),
            np.array(self.diameters, dtype=np.float64),
        )


def to_svg(pattern: DotPattern) -> str:
    """The stencil as SVG in millimetres: one circle per hole, cut lines only."""
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{pattern.width_mm:.3f}mm"'
        f' height="{pattern.height_mm:.3f}mm"'
        f' viewBox="0 0 {pattern.width_mm:.3f} {pattern.height_mm:.3f}">',
        f'<rect x="0" y="0" width="{pattern.width_mm:.3f}" height="{pattern.height_mm:.3f}"'
        ' fill="none" stroke="#0000ff" stroke-width="0.05"/>',
        '<g fill="none" stroke="#ff0000" stroke-width="0.05">',
    ]
    for (cx, cy), d in zip(pattern.centers_mm, pattern.diameters_mm, strict=True):
        lines.append(f'<circle cx="{cx:.3f}" cy="{cy:.3f}" r="{d / 2:.3f}"/>')
    lines += ["</g>", "</svg>", ""]
    return "\n".join(lines)


@functools.cache
def texture(
    *,
    density_per_mm2: float,
    min_diameter_mm: float,
    max_diameter_mm: float,
    randomness: float,
    seed: int,
    width_mm: float,
    height_mm: float,
    mm_per_px: float,
    dot_albedo: float,
) -> np.ndarray:
    """The printed sheet as a float32 albedo raster (1 latex, ``dot_albedo`` ink), cached.

    Row index runs along the sheet's height, column along its width; pixel ``(r, c)``
    covers ``[c, c+1) * mm_per_px`` by ``[r, r+1) * mm_per_px``. Edges are antialiased.
    """
    import cv2

    pattern = generate(
        density_per_mm2=density_per_mm2,
        min_diameter_mm=min_diameter_mm,
        max_diameter_mm=max_diameter_mm,
        randomness=randomness,
        seed=seed,
        width_mm=width_mm,
        height_mm=height_mm,
    )
    shape = (int(math.ceil(height_mm / mm_per_px)), int(math.ceil(width_mm / mm_per_px)))
    ink = np.zeros(shape, np.uint8)
    shift = 4  # sub-pixel precision of cv2 drawing: 1/16 px
    for (cx, cy), d in zip(pattern.centers_mm, pattern.diameters_mm, strict=True):
        # Pixel centres sit at (i + 0.5) * mm_per_px.
        centre = (
            int(round((cx / mm_per_px - 0.5) * (1 << shift))),
            int(round((cy / mm_per_px - 0.5) * (1 << shift))),
        )
        # cv2 fills a circle half a pixel wider than its radius; take it back.
        radius = int(round((d / 2 / mm_per_px - 0.5) * (1 << shift)))
        cv2.circle(ink, centre, max(radius, 1), 255, -1, cv2.LINE_AA, shift)
    albedo = 1.0 - (1.0 - dot_albedo) * (ink.astype(np.float32) / 255.0)
    albedo.setflags(write=False)
    return albedo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sim.pattern", description="Write a dot-pattern stencil as SVG."
    )
    parser.add_argument("--density", type=float, required=True, help="dots per mm^2")
    parser.add_argument("--min-diameter-mm", type=float, required=True)
    parser.add_argument("--max-diameter-mm", type=float, required=True)
    parser.add_argument("--randomness", type=float, required=True, help="0 lattice .. 1 random")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width-mm", type=float, default=80.0, help="sheet width")
    parser.add_argument("--height-mm", type=float, default=120.0, help="sheet height")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        pattern = generate(
            density_per_mm2=args.density,
            min_diameter_mm=args.min_diameter_mm,
            max_diameter_mm=args.max_diameter_mm,
            randomness=args.randomness,
            seed=args.seed,
            width_mm=args.width_mm,
            height_mm=args.height_mm,
        )
    except ValueError as err:
        parser.error(str(err))
    args.out.write_text(to_svg(pattern))
    reached, asked = pattern.density_per_mm2, pattern.requested_density_per_mm2
    print(
        f"{args.out}: {len(pattern.diameters_mm)} dots on {args.width_mm:g} x {args.height_mm:g} mm,"
        f" {reached:.4f} dots/mm^2 ({asked:g} asked)"
    )
    if reached < asked * (1.0 - SHORT_FRACTION):
        print(
            f"density not reached: {reached:.4f} of the {asked:g} dots/mm^2 asked;"
            f" {args.min_diameter_mm:g}-{args.max_diameter_mm:g} mm dots with 0.2 mm gaps do not"
            " fit that densely at random. Lower --max-diameter-mm (or --min-diameter-mm), or"
            " ask a lower --density.",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
