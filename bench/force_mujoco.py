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
  not carry beside each bag (``bench.worlds_grasps.recorded_frames``). Their loads point
  along tool y and z, so they also determine the tangential stiffness along y.
* **the truth of slip**: the object sliding over the latex. The membrane's mesh
  vertices are the latex's material points (the dots the cameras see are drawn on
  them); a point of the contact sticks while it stays put in the object's frame. Per
  bubble and frame, the share of the points touching the object in this frame and the
  last that moved over it faster than :data:`SLIP_SPEED_M_PER_S` (3 mm/s: 0.1 mm a
  frame at 30 Hz; MuJoCo's soft friction lets a contact creep, 0.003-0.005 mm a frame
  held still and up to 0.09 mm a frame under a growing load while every point holds,
  and a whole patch sliding out moves at 4-40 times the threshold), averaged
  over the frame and its neighbours (:data:`SMOOTH_FRAMES`: a mesh of 12 mm leaves
  10-20 points in a patch, so one point more or less moves the share by 5-10%). The
  edge slips from :data:`EDGE_SHARE` of the points, the whole patch from
  :data:`PATCH_SHARE` (:func:`slipping_share`, :func:`latex_slip`), from the grasp
  monitor's stable grasp on (the jaws closing make the membrane conform to the object,
  its points moving over it as the patch forms). The engine's own
  flag, the share of its contacts at the friction cone's limit, was the truth before:
  the rim's contacts, pressed by almost nothing, sit at their cone from the first
  shear and flicker in and out of it (0.02-0.56 from frame to frame on a mug being
  filled whose points all still stuck), so its first half-share came up to 26 frames
  (median 5) before a third of the latex slid, and passed a half on bubbles whose
  latex never slid. ``world.sim`` reports its patch's slipping area directly.

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
SLIP_SPEED_M_PER_S = 0.003
SMOOTH_FRAMES = 3
EDGE_SHARE = 1.0 / 3.0
PATCH_SHARE = 0.9
MESH_M = 0.008
CALIBRATION = ROOT / "models" / "force" / "mujoco.json"


def slipping_share(fraction: float) -> float:
    """The share of the contact's points sliding over the object, as ``world.sim``'s
    slipping area: 0 under :data:`EDGE_SHARE`, 1 from :data:`PATCH_SHARE`."""
    if fraction >= PATCH_SHARE:
        return 1.0
    return fraction if fraction >= EDGE_SHARE else 0.0


def sliding_share(
    before: np.ndarray, after: np.ndarray, touching: np.ndarray, period_secs: float
) -> float:
    """The share of the points touching the object in both frames (``touching``) that
    moved over it faster than :data:`SLIP_SPEED_M_PER_S` between the two: ``before`` and
    ``after`` are the same material points in the object's frame, ``(n, 3)`` (0 when
    no point touched in both)."""
    if not touching.any():
        return 0.0
    moved = np.linalg.norm(after[touching] - before[touching], axis=1)
    return float(np.mean(moved > SLIP_SPEED_M_PER_S * period_secs))


def latex_slip(
    instants: list[sim.Instant], scene: sim.Scene, stable: list[bool]
) -> list[dict[str, float]]:
    """Per frame and bubble, the truth of slip (the module docstring): the share of the
    contact's points sliding over the object, smoothed over :data:`SMOOTH_FRAMES`,
    through :func:`slipping_share`; zero where the grasp is not ``stable`` (the grasp
    monitor's: while the jaws close the membrane conforms to the object, and its points
    move over it as the patch forms, which is no slip)."""
    from geometry.se3 import invert
    from sim.mujoco.mesh import contact_tolerance_m

    geometry = scene.gripper_geometry()
    field = scene.object_model().field
    raw = np.zeros((len(instants), len(SIDES)))
    last: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for i, inst in enumerate(instants):
        snap = inst.snapshot
        assert snap.membranes_f is not None, "a MuJoCo snapshot carries its membranes"
        tolerance = contact_tolerance_m(float(snap.membrane_spacing_m))
        for k, side in enumerate(SIDES):
            object_from_finger = invert(snap.tool_from_object) @ geometry.tool_from_finger(
                side, snap.width_m
            )
            surface = np.asarray(snap.membranes_f[side], np.float64)
            local = surface @ object_from_finger[:3, :3].T + object_from_finger[:3, 3]
            touching = field.value(local) < tolerance
            if side in last:
                before, touched = last[side]
                raw[i, k] = sliding_share(
                    before, local, touched & touching, scene.frame_period_secs
                )
            last[side] = (local, touching)
    kernel = np.ones(SMOOTH_FRAMES) / SMOOTH_FRAMES
    smooth = np.stack([np.convolve(raw[:, k], kernel, "same") for k in range(len(SIDES))], 1)
    return [
        {s: slipping_share(float(row[k])) if held else 0.0 for k, s in enumerate(SIDES)}
        for row, held in zip(smooth, stable, strict=True)
    ]


def grasps(
    count: int, spacing_m: float, workdir: Path, settings: tuple[str, ...] = ()
) -> list[Recorded]:
    """``bench.worlds``' grasps on the MuJoCo world (recorded once per scene and mesh in
    ``workdir``, shared with ``bench.worlds``), with the engine's wrench and the latex
    sliding over the object (:func:`latex_slip`) as the truth; the features of
    ``settings`` (default: every one)."""
    from bench import worlds_grasps
    from runtime.bag import BagReader

    rng = np.random.default_rng(worlds_grasps.SEED)
    out = []
    for k in progress(range(count), "bench.force mujoco"):
        scene_path, bag, _ = worlds_grasps.recorded_grasp(k, rng, spacing_m, workdir)
        instants = worlds_grasps.replay_mujoco(scene_path, bag)
        with BagReader(bag) as reader:
            truths = [m.decode() for m in reader.messages(["world/wrench"])]
        scene = sim.load_scene(scene_path)
        rec = features_of(instants, scene, truths, settings)
        truth = latex_slip(instants, scene, [f.stable for f in rec.frames])
        for f, slipping in zip(rec.frames, truth, strict=True):
            f.slipping = slipping
        out.append(rec)
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
    settings: tuple[str, ...] = (),
) -> list[Recorded]:
    """Loaded grasps ``0 .. count - 1`` (:func:`loaded_spec`) on MuJoCo: a free object
    under the engine's gravity, filled or pulled past the stick limit, so it slips on
    MuJoCo's friction. Recorded once per scene and mesh in ``workdir`` (as
    ``bench.worlds``' grasps); truth: the engine's wrench, the latex sliding over the
    object (:func:`latex_slip`) and the object's slide in the hand. The features of
    ``settings`` (default: every one); with ``still``, the still holds instead (the
    default setting's only)."""
    from bench import worlds_grasps
    from runtime.bag import BagReader
    from sim.mujoco.world import DROPPED_M

    out = []
    for k in progress(range(count), "bench.force mujoco loaded"):
        spec = loaded_spec(k, duration_secs, still=still)
        scene_path, bag, _ = worlds_grasps.recorded_scene(
            f"force_{spec.load}_{k}", spec.doc, spacing_m, workdir, frames=True
        )
        instants = worlds_grasps.replay_mujoco(scene_path, bag)
        with BagReader(bag) as reader:
            truths = [m.decode() for m in reader.messages(["world/wrench"])]
        rec = features_of(instants, spec.scene, truths, (DEFAULT_SETTING,) if still else settings)
        truth = worlds_grasps.recorded_frames(bag)
        rec.frames = [
            dataclasses.replace(
                f, slipping=slipping, slide_m=np.asarray(t["slide_m"]), drop_m=DROPPED_M
            )
            for f, t, slipping in zip(
                rec.frames,
                truth,
                latex_slip(instants, spec.scene, [f.stable for f in rec.frames]),
                strict=True,
            )
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
    for k, rec in enumerate(grasp_recs + slide_recs):
        frames = [
            dataclasses.replace(f, features=feats)
            for f, feats in zip(rec.frames, rec.by_setting[DEFAULT_SETTING], strict=True)
        ]
        data += samples(frames, k)
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
        # The calibration fits the default flow setting's features only.
        grasp_recs = grasps(args.grasps, args.mesh, workdir, (DEFAULT_SETTING,))
        slide_recs = loaded(args.slides, args.mesh, workdir, settings=(DEFAULT_SETTING,))
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
