"""The bubble as a force sensor on the second world (MuJoCo): grasps, slips, calibration.

The engine computes the contact forces (``sim.mujoco``), which no one here tuned; this
module turns its runs into the force estimators' data, as ``bench.force_data`` does for
``world.sim``:

* **grasps** (:func:`grasps`): ``bench.worlds``' grasps (the four objects in turn, a
  12 N grasp, a 4 mm slide along the fingers), recorded once per scene and mesh in a
  work folder shared with ``bench.worlds``, the engine's wrench as the truth.
* **loaded grasps** (:func:`loaded`): ``bench.force_data``'s draws (an object held at
  5-12 N, then filled or pulled in the tool's (y, z) plane, many past the stick limit)
  with the ``slip`` effect, which on MuJoCo makes the object free once the jaws hold
  it: the engine's gravity on its mass (growing as it is filled) and the pull against
  MuJoCo's friction, so it slips and falls out on physics no one here wrote. Recorded
  once per scene and mesh as the grasps are, with the per-frame truth the messages do
  not carry beside each bag (``bench.worlds.recorded_frames``). Their loads point
  along tool y and z, so they also determine the tangential stiffness along y.
* **the truth of slip**: the engine's share of a bubble's contacts at their friction
  cone's limit. In MuJoCo's soft contact the rim's contacts, pressed by almost nothing,
  sit at their cone from the first shear (0.1-0.25 of them while the load is a tenth of
  the friction), and the share climbs with the load to 0.9-1.0 once the tangential force
  reaches the friction. So the edge's slip is taken as :data:`EDGE_SHARE` of the
  contacts at the limit and the whole patch's as :data:`PATCH_SHARE`
  (:func:`slipping_share`); ``world.sim`` reports its patch's slipping area directly.

The calibration file of the MuJoCo world (both estimators, the friction and the slip
limits, fitted on its grasps and loaded grasps)::

    python -m bench.force_mujoco --grasps 4 --slides 4 --out models/force/mujoco.json

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
from bench.force_data import (
    DEFAULT_SETTING,
    ROOT,
    GraspSpec,
    Recorded,
    draw,
    features_of,
    samples,
)
from geometry.gripper import SIDES
from perception.force.estimators import Calibration, calibrate

LOADED_SEED = 300  # other draws than world.sim's calibration and held-out grasps
STILL_SEED = 408
REFLEX_SEED = 600
LOADED_SECS = 3.0
# A held object's speed in the hand over which it is taken as sliding out (the reflex
# sweep's drops on MuJoCo: the shell's give under a growing load moves it under 10 mm/s).
DROP_SPEED_M_PER_S = 0.03
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


def loaded_spec(k: int, duration_secs: float = LOADED_SECS, *, still: bool = False) -> GraspSpec:
    """The ``k``-th loaded grasp: ``bench.force_data``'s draw of seed ``LOADED_SEED +
    3 k`` (the four objects in turn), a filling or a pull (alternating, so that each half
    of a set has both); with ``still``, the ``k``-th still hold (its weight only, seeds
    from ``STILL_SEED``)."""
    if still:
        return draw(STILL_SEED + 3 * k, duration_secs=duration_secs, load="still")
    kind = ("fill", "pull")[(k + k // 4) % 2]
    return draw(LOADED_SEED + 3 * k, duration_secs=duration_secs, load=kind)


def reflex_seeds(count: int) -> list[int]:
    """The seeds of the reflex sweep's fillings on MuJoCo (the four objects in turn)."""
    return [REFLEX_SEED + 3 * k for k in range(count)]


def loaded(
    count: int,
    spacing_m: float,
    workdir: Path,
    *,
    duration_secs: float = LOADED_SECS,
    still: bool = False,
) -> list[Recorded]:
    """Loaded grasps ``0 .. count - 1`` (:func:`loaded_spec`) on MuJoCo: a free object
    under the engine's gravity, filled or pulled past the stick limit, so it slips on
    MuJoCo's friction. Recorded once per scene and mesh in ``workdir`` (as
    ``bench.worlds``' grasps), the default feature setting; truth: the engine's wrench,
    its slipping share (:func:`slipping_share`, from the hand letting go on) and the
    object's slide in the hand. Every feature setting's features; with ``still``, the
    still holds instead (the default setting's only)."""
    from bench import worlds
    from runtime.bag import BagReader
    from sim.mujoco.world import DROPPED_M

    out = []
    for k in progress(range(count), "bench.force mujoco loaded"):
        spec = loaded_spec(k, duration_secs, still=still)
        scene_path, bag, _ = worlds.recorded_scene(
            f"force_{spec.load}_{k}", spec.doc, spacing_m, workdir, frames=True
        )
        instants = worlds.replay_mujoco(scene_path, bag)
        with BagReader(bag) as reader:
            truths = [m.decode() for m in reader.messages(["world/wrench"])]
        rec = features_of(instants, spec.scene, truths, (DEFAULT_SETTING,) if still else ())
        truth = worlds.recorded_frames(bag)
        rec.frames = [
            dataclasses.replace(
                f,
                slipping={
                    s: slipping_share(t["slipping"][i]) if any(t["load_n"]) else 0.0
                    for i, s in enumerate(SIDES)
                },
                slide_m=np.asarray(t["slide_m"]),
                drop_m=DROPPED_M,
            )
            for f, t in zip(rec.frames, truth, strict=True)
        ]
        out.append(rec)
    return out


def simulator(scene: sim.Scene, spacing_m: float) -> sim.Simulator:
    """A simulator of ``scene`` whose world is MuJoCo's (run live: for closed loops)."""
    from sim.mujoco.model import ShellSpec
    from sim.mujoco.world import MujocoWorld

    out = sim.Simulator(scene)
    out.world = MujocoWorld(scene, ShellSpec(mesh_spacing_m=spacing_m))  # type: ignore[assignment]
    return out


def calibrate_mujoco(
    grasp_recs: list[Recorded], slide_recs: list[Recorded], source: str
) -> Calibration:
    """Every estimator and the slip limits fitted on MuJoCo's grasps and loaded grasps."""
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
    parser.add_argument("--slides", type=int, default=4, help="loaded grasps (filled, pulled)")
    parser.add_argument("--mesh", type=float, default=MESH_M, help="membrane mesh edge, m")
    parser.add_argument("--out", type=Path, default=CALIBRATION)
    args = parser.parse_args(argv)
    if args.grasps < 1 or args.slides < 1:
        parser.error("--grasps and --slides must be >= 1")
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(os.environ.get("WORLDS_DIR", tmp))
        workdir.mkdir(parents=True, exist_ok=True)
        grasp_recs = grasps(args.grasps, args.mesh, workdir)
        slide_recs = loaded(args.slides, args.mesh, workdir)
    source = (
        f"bench.force_mujoco: {args.grasps} grasps of bench.worlds' seed and {args.slides}"
        f" loaded grasps (filled, pulled; a free object), {args.mesh * 1000:g} mm mesh"
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
