"""Each bubble's frames with nothing touching it, averaged: a no-contact reference.

The jaws stay open (the scene's gripper commands dropped; the auto-labelling world's effects) and the object stays where the
scene puts it, out of the bubbles' reach at the open width; ``frames`` frames are
rendered with the scene's effects (the ToF noise included, each frame its own draw) and
averaged per pixel over the frames where the pixel is valid. A pixel invalid in half
the frames or more stays invalid (NaN): the rim's grazing pixels, which the camera loses
at rest too. What a camera node would average while the gripper is open and still
(``perception.contact`` does so for its reference).

    python -m sim.free_bubble OUT.npz [--scene scenes/mug_grasp.yaml] [--frames 16]

writes ``depth_left_m``, ``depth_right_m`` (float32 m, NaN invalid), ``ir_left``,
``ir_right`` (float32 amplitude, 0 invalid), read with ``np.load(..., allow_pickle=False)``
(the tactile classifier's ``--free-bubble``, docs/classifier.md).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from geometry.gripper import SIDES
from sim import Simulator, load_scene

DEFAULT_SCENE = "scenes/mug_grasp.yaml"
# The auto-labelling world's effects (nodes/autolabel.py): no dot pattern, the ToF noise.
EFFECTS = ("membrane", "depth", "ir", "tof_noise", "pressure", "gripper", "ground_truth")


def free_bubble_frames(
    scene_path: str | Path = DEFAULT_SCENE, frames: int = 16
) -> dict[str, np.ndarray]:
    """Both bubbles' free depth and IR, averaged over ``frames`` (module docstring).

    Raises:
        ValueError: ``frames`` < 1, or an object that touches a bubble with the jaws open.
    """
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    scene = load_scene(scene_path)
    gripper = dataclasses.replace(scene.gripper, commands=())
    scene = dataclasses.replace(
        scene, gripper=gripper, effects=EFFECTS, duration_secs=max(frames, 2) / 10.0
    )
    simulator = Simulator(scene)
    depth: dict[str, list[np.ndarray]] = {s: [] for s in SIDES}
    ir: dict[str, list[np.ndarray]] = {s: [] for s in SIDES}
    for _ in range(frames):
        inst = simulator.render_snapshot(simulator.world.step())
        for side in SIDES:
            if inst.masks and inst.masks[side].mask.any():
                raise ValueError(f"{scene_path}: the object touches the {side} bubble, jaws open")
            depth[side].append(inst.images[side].depth_m.astype(np.float64))
            ir[side].append(inst.images[side].ir.astype(np.float64))
    out: dict[str, np.ndarray] = {}
    for side in SIDES:
        d = np.stack(depth[side])
        valid = np.isfinite(d)
        count = valid.sum(axis=0)
        mean = np.where(valid, d, 0.0).sum(axis=0) / np.maximum(count, 1)
        kept = count * 2 > frames
        out[f"depth_{side}_m"] = np.where(kept, mean, np.nan).astype(np.float32)
        amp = np.stack(ir[side])
        lit = amp > 0
        mean_ir = np.where(lit, amp, 0.0).sum(axis=0) / np.maximum(lit.sum(axis=0), 1)
        out[f"ir_{side}"] = np.where(lit.sum(axis=0) * 2 > frames, mean_ir, 0.0).astype(np.float32)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim.free_bubble", description=__doc__.split("\n")[0]
    )
    p.add_argument("out", help="the .npz to write")
    p.add_argument("--scene", default=DEFAULT_SCENE)
    p.add_argument("--frames", type=int, default=16)
    args = p.parse_args(argv)
    arrays = free_bubble_frames(args.scene, args.frames)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **arrays)  # type: ignore[arg-type]
    for side in SIDES:
        d = arrays[f"depth_{side}_m"]
        print(
            f"{side}: depth {np.nanmin(d) * 1000:.1f} to {np.nanmax(d) * 1000:.1f} mm, "
            f"{np.isnan(d).mean():.1%} invalid; IR median {np.median(arrays[f'ir_{side}']):.0f}"
        )
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
