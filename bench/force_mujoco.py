"""The bubble as a force sensor on the second world (MuJoCo): grasps, slips, calibration.

The engine computes the contact forces (``sim.mujoco``), which no one here tuned; this
module turns its runs into the force estimators' data, as ``bench.force_data`` does for
``world.sim``:

* **grasps** (:func:`grasps`): ``bench.worlds``' grasps (the four objects in turn, a
  12 N grasp, a 4 mm slide along the fingers), recorded once per scene and mesh in a
  work folder shared with ``bench.worlds``, the engine's wrench as the truth.
* **slides** (:func:`slides`): the same grasps with the hand sliding the object
  :data:`SLIDE_M` along tool z from :data:`HOLD_SECS` to :data:`END_SECS`: past the
  stick limit, so the patch slips (the engine's friction cone). Run live: the
  recording keeps no share of slipping contacts.
* **the truth of slip**: the engine's share of a bubble's contacts at their friction
  cone's limit. In MuJoCo's soft contact the rim's contacts, pressed by almost nothing,
  sit at their cone from the first shear (0.1-0.25 of them while the load is a tenth of
  the friction), and the share climbs with the load to 0.9-1.0 once the tangential force
  reaches the friction. So the edge's slip is taken as :data:`EDGE_SHARE` of the
  contacts at the limit and the whole patch's as :data:`PATCH_SHARE`
  (:func:`slipping_share`); ``world.sim`` reports its patch's slipping area directly.

The calibration file of the MuJoCo world (both estimators, the friction and the slip
limits, fitted on its grasps and slides)::

    python -m bench.force_mujoco --grasps 4 --slides 2 --out models/force/mujoco.json

``bench.force`` calibrates on some of these and scores on others.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

import sim
from bench.common import progress
from bench.force_data import DEFAULT_SETTING, ROOT, Recorded, features_of, samples
from geometry.gripper import SIDES
from perception.force.estimators import Calibration, calibrate

HOLD_SECS = 1.2
SLIDE_M = 0.015
END_SECS = 2.4
EDGE_SHARE = 0.5
PATCH_SHARE = 0.9
MESH_M = 0.008
CALIBRATION = ROOT / "models" / "force" / "mujoco.json"


def slipping_share(fraction: float) -> float:
    """The engine's share of contacts at their cone's limit, as ``world.sim``'s slipping
    area: 0 under :data:`EDGE_SHARE` (the rim alone), 1 from :data:`PATCH_SHARE`."""
    if fraction >= PATCH_SHARE:
        return 1.0
    return fraction if fraction >= EDGE_SHARE else 0.0


def grasps(count: int, spacing_m: float, workdir: Path) -> list[Recorded]:
    """``bench.worlds``' grasps on the MuJoCo world (recorded once per scene and mesh in
    ``workdir``, shared with ``bench.worlds``), with the engine's wrench as the truth."""
    from bench import worlds
    from runtime.bag import BagReader

    rng = np.random.default_rng(worlds.SEED)
    out = []
    for k in progress(range(count), "bench.force mujoco"):
        scene_path, bag, _ = worlds.recorded_grasp(k, rng, spacing_m, workdir)
        instants = worlds.replay_mujoco(scene_path, bag)
        with BagReader(bag) as reader:
            truths = [m.decode() for m in reader.messages(["world/wrench"])]
        out.append(features_of(instants, sim.load_scene(scene_path), truths))
    return out


def slide_scene(k: int, rng: np.random.Generator) -> sim.Scene:
    """The ``k``-th grasp of ``bench.worlds`` (drawn from ``rng`` in turn), slid past the
    stick limit."""
    from bench import worlds

    doc = worlds.grasp_scene(k, rng)
    start = doc["trajectory"][0]
    end = [start["xyz_m"][0], start["xyz_m"][1], start["xyz_m"][2] + SLIDE_M]
    doc["name"] = f"force_slide_{k}"
    doc["duration_secs"] = END_SECS
    doc["trajectory"] = [
        start,
        {**start, "t_secs": HOLD_SECS},
        {**start, "t_secs": END_SECS, "xyz_m": end},
    ]
    return sim.scene_from_dict(doc, path=f"<force slide {k}>")


def slides(count: int, spacing_m: float, *, first: int = 0) -> list[Recorded]:
    """Slides ``first .. first + count - 1`` run live on MuJoCo, the default feature
    setting, the engine's wrench and slipping share (:func:`slipping_share`) as truth."""
    from bench import worlds
    from sim.mujoco.model import ShellSpec
    from sim.mujoco.world import MujocoWorld

    rng = np.random.default_rng(worlds.SEED)
    scenes = [slide_scene(k, rng) for k in range(first + count)][first:]
    out = []
    for k in progress(range(len(scenes)), "bench.force mujoco slides"):
        scene = scenes[k]
        world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=spacing_m))
        simulator = sim.Simulator(scene)
        instants, truths = [], []
        while not world.done:
            snap = world.step()
            instants.append(simulator.render_snapshot(snap))
            truths.append(world.wrench_truth(sim.stamp_of(snap)))
        rec = features_of(instants, scene, truths, (DEFAULT_SETTING,))
        rec.frames = [
            dataclasses.replace(f, slipping={s: slipping_share(f.slipping[s]) for s in SIDES})
            for f in rec.frames
        ]
        out.append(rec)
    return out


def calibrate_mujoco(
    grasp_recs: list[Recorded], slide_recs: list[Recorded], source: str
) -> Calibration:
    """Every estimator and the slip limits fitted on MuJoCo's grasps and slides."""
    data = []
    for rec in grasp_recs + slide_recs:
        frames = [
            dataclasses.replace(f, features=feats)
            for f, feats in zip(rec.frames, rec.by_setting[DEFAULT_SETTING], strict=True)
        ]
        data += samples(frames)
    return calibrate(data, rig="mujoco", source=source)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.force_mujoco")
    parser.add_argument("--grasps", type=int, default=4, help="bench.worlds' grasps")
    parser.add_argument("--slides", type=int, default=2, help="grasps slid past the stick")
    parser.add_argument("--mesh", type=float, default=MESH_M, help="membrane mesh edge, m")
    parser.add_argument("--out", type=Path, default=CALIBRATION)
    args = parser.parse_args(argv)
    if args.grasps < 1 or args.slides < 1:
        parser.error("--grasps and --slides must be >= 1")
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(os.environ.get("WORLDS_DIR", tmp))
        workdir.mkdir(parents=True, exist_ok=True)
        grasp_recs = grasps(args.grasps, args.mesh, workdir)
    slide_recs = slides(args.slides, args.mesh)
    source = (
        f"bench.force_mujoco: {args.grasps} grasps and {args.slides} slides of"
        f" bench.worlds' seed, {args.mesh * 1000:g} mm mesh"
    )
    cal = calibrate_mujoco(grasp_recs, slide_recs, source)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cal.save(args.out)
    print(
        f"wrote {args.out} ({cal.samples} samples; friction {cal.friction:.3f}; slip limits"
        f" {cal.slip_edge_m_per_pa * 1e6:.3f}, {cal.slip_patch_m_per_pa * 1e6:.3f} um/Pa"
        f" from {cal.slip_onsets} onsets)",
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
