"""Golden images and determinism: the same scene and seed give bit-identical frames.

The golden file holds the mug grasp at t = 1.5 s (all effects, seeded), downsampled 8x,
in a few kilobytes. Regenerate it (after a deliberate change to the renderer) with:

    .venv/bin/python -m tests.sim.test_golden --regenerate
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np

import sim

GOLDEN = Path(__file__).parent / "golden" / "mug_grasp_t1.5.npz"
SCENE = "scenes/mug_grasp.yaml"
T_SECS = 1.5


def _digest(inst: sim.Instant) -> str:
    h = hashlib.sha256()
    for side in ("left", "right"):
        h.update(inst.images[side].depth_m.tobytes())
        h.update(inst.images[side].ir.tobytes())
    return h.hexdigest()


def _small(inst: sim.Instant) -> dict[str, np.ndarray]:
    out = {}
    for side in ("left", "right"):
        out[f"{side}_depth_mm"] = (inst.images[side].depth_m[::8, ::8] * 1000).astype(np.float16)
        out[f"{side}_ir"] = inst.images[side].ir[::8, ::8]
    return out


def test_same_scene_and_seed_are_bit_identical() -> None:
    a = sim.render(SCENE, T_SECS)
    b = sim.render(SCENE, T_SECS)
    assert _digest(a) == _digest(b)
    other = sim.load_scene(SCENE)
    import dataclasses

    c = sim.render(dataclasses.replace(other, seed=other.seed + 1), T_SECS)
    assert _digest(c) != _digest(a)


def test_golden_images() -> None:
    inst = sim.render(SCENE, T_SECS)
    golden = np.load(GOLDEN)
    for key, value in _small(inst).items():
        want = golden[key]
        assert want.shape == value.shape
        if key.endswith("_ir"):
            assert np.abs(want.astype(int) - value.astype(int)).max() <= 2, key
        else:
            np.testing.assert_array_equal(np.isnan(want), np.isnan(value))
            np.testing.assert_allclose(
                value.astype(float), want.astype(float), atol=0.05, equal_nan=True
            )


if __name__ == "__main__" and "--regenerate" in sys.argv:
    GOLDEN.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(GOLDEN, **_small(sim.render(SCENE, T_SECS)))
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size} bytes)")
