"""The bubble as a force sensor: ``python -m bench.force``.

Four sweeps on simulated grasps (``bench.force_data``: random objects, grips and loads,
every sensor effect; the true wrench and slip from the ``wrench`` and ``slip`` effects):

* ``wrench``: error against time per method (``physics``, ``ridge``) and per dot-flow
  setting (Farneback at half and quarter resolution, DIS at half), on both worlds: each
  setting's features of the *calibration* grasps fit both methods, which are scored on
  *held-out* grasps. ``world.sim``: seeds ``0 .. n-1`` against ``n .. 2n-1`` (other
  objects, grips and loads). MuJoCo (``world.mujoco``, whose engine computes the
  contact forces): ``bench.worlds``' grasps (the four objects in turn, a 12 N grasp,
  a 4 mm slide along the fingers; recorded once per scene and mesh in ``out/worlds``
  or ``WORLDS_DIR``, shared with ``bench.worlds``), the first half against the second,
  an 8 mm membrane mesh (12 mm with ``--quick``). The handover sweep is
  ``world.sim``'s only.
  Errors per bubble and frame in contact while the object is held (slid less than
  ``DROP_M``): force (N), torque (N m), force in percent of
  the bubble's true load; median and p90; plus the share of frames within the goal
  (10% or 0.3 N, whichever is larger); and on ``world.sim`` the dots' error
  (``shift_err``: the core's shift against the object's slide in the hand since the
  tare, while the patch sticks, mm). Time: features and estimate of both bubbles per
  frame on one core (the least of ``TIMING_REPEATS`` runs of the first test grasp's
  frames, thread CPU time), and the rate it allows.
* ``slip``: per bubble and held-out grasp whose patch slipped (truth), the detector's
  edge onset against the truth's (the first frame any of the patch slips) and its patch
  onset against the first frame the whole patch slips: detected (within
  ``MAX_LATE_FRAMES`` after), latency in frames and ms (negative: before the truth;
  the edge's is the detector's first onset of either kind, a whole patch sliding has
  its edge slipping too); a true onset in the recording's last ``MIN_SCORED_FRAMES``
  is not scored (``cut_at_end``); false alarms per minute of still holding (any onset
  while the truth is stuck and stays so for ``MAX_EARLY_FRAMES``). The detector is
  referenced at the grasp monitor's stable grasp (``Frame.stable``), as the ``slip``
  node is; the truth's onsets are scored from there. Each edge cue
  (``SlipParams.edge_cue``) side by side: ``onset_edge``, ``onset_patch`` with the
  default (``both``: the earlier of the dots' and the stick limit's, the limit's only
  where the calibration's edge onsets spread little), ``onset_edge_limit``,
  ``onset_patch_limit`` with the stick limit's alone, ``onset_edge_dots``,
  ``onset_patch_dots`` with the share of the dots leaving the patch's rigid motion
  alone (the whole patch's cue is the same; its onsets
  differ by the episodes the edge opens). On both worlds: ``world.sim``'s held-out grasps and
  long still holds (the detector's limits from its calibration grasps); MuJoCo's
  loaded grasps (``bench.force_mujoco``: a free object under the engine's gravity,
  filled or pulled past the stick limit; its truth of slip; the limits fitted on the
  first half of them with the calibration grasps, the second half scored) and still
  holds. The wrench sweep scores MuJoCo's held-out loaded grasps too (``mujoco_loaded``:
  calibrated on the calibration grasps and the first half of the loaded ones, whose
  loads along tool y and z determine the tangential stiffness along both).
* ``reflex``: grasps whose load outgrows the grip (fillings, and weights held too
  lightly), run closed loop twice, without and with the reflex (slip onset: raise the
  grip, bounded per object, ``perception.force.reflex``); kept (slid less than
  ``DROP_M``) or dropped, and dropped with the grip at the object's bound (a filling
  heavier than the bound can hold: the bound's doing, not the reflex's); of the open
  loop's drops, the share the reflex kept (``saved_fraction``), and the share of those
  not lost at the bound (``saved_within_bound_fraction``). On both
  worlds: MuJoCo's run live (a free object being filled, the MuJoCo calibration); there
  the shell gives centimetres under a load, so kept is: still touching both bubbles at
  the end and moving slower than ``force_mujoco.DROP_SPEED_M_PER_S``.
* ``handover``: the handover's pull (``scenes/handover_task.yaml`` with the pull's start
  drawn as ``bench.tasks`` draws it): frames from the pull's start to the release
  decision by the shear rule (the paper's: 1.5 px for 3 frames) and by the force rule
  (the supervisor's with ``wrench`` wired), in data time; and the held-still scene's
  false releases. Decisions only: the graph's latency adds the pipeline's
  (``bench.tasks``).

By default: 8 ``world.sim`` grasps per set, 8 MuJoCo grasps, 8 MuJoCo loaded grasps,
4 still holds of 15 s on ``world.sim`` (and as many of 6 s on MuJoCo), 8 reflex grasps
(4 on MuJoCo), 4 handovers; ``--grasps``, ``--mujoco``, ``--slides`` (MuJoCo's loaded
grasps), ``--still``, ``--reflex``, ``--mujoco-reflex`` and ``--handover`` set them.
``--quick`` runs two grasps per set of ``world.sim``, one MuJoCo grasp, one loaded
grasp and one still hold of 1.5 s at a 12 mm mesh (scored on themselves: a smoke test,
not held out), one reflex grasp on each world and one handover. ``--sweeps`` runs some
of them (``--sweeps slip``: the slip sweep alone, with the default flow setting's
features only).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

import sim
from bench import force_mujoco
from bench.common import Row, main, median, one_core, percentile, progress
from bench.force_data import (
    DEFAULT_SETTING,
    SETTINGS,
    Bubbles,
    Recorded,
    draw,
    features_of,
    held,
    samples,
    shift_errors_m,
)
from bench.force_loop import handover_rows, reflex_rows
from geometry.gripper import SIDES
from perception.force.estimators import METHODS, Calibration, calibrate, estimate
from perception.force.slip import SlipDetector, SlipParams

TIMING_REPEATS = 3
MAX_LATE_FRAMES = 15
MAX_EARLY_FRAMES = 15
MIN_SCORED_FRAMES = 5  # a true onset this near the recording's end is not scored
GOAL_FRACTION, GOAL_N = 0.10, 0.3
# SlipParams.edge_cue, each scored (the default first)
EDGE_CUES: tuple[Literal["both", "limit", "dots"], ...] = ("both", "limit", "dots")


def record_all(
    seed: int, duration_secs: float, *, load: str | None = None, settings: tuple[str, ...] = ()
) -> Recorded:
    """Render one grasp of the simulated world once; every setting (default: all)
    extracts its features from the same frames."""
    spec = draw(seed, duration_secs=duration_secs, load=load)
    simulator = sim.Simulator(spec.scene)
    instants = []
    while not simulator.world.done:
        instants.append(simulator.step())
    truths = [inst.wrench for inst in instants]
    assert all(t is not None for t in truths)
    return features_of(instants, spec.scene, truths, settings)  # type: ignore[arg-type]


def time_setting(
    seed: int, duration_secs: float, setting: str, cal: Calibration, repeats: int
) -> float:
    """Seconds per frame (both bubbles: features and the physics estimate), the least
    of ``repeats`` runs over one grasp's frames, thread CPU time."""
    spec = draw(seed, duration_secs=duration_secs)
    simulator = sim.Simulator(spec.scene)
    instants = []
    while not simulator.world.done:
        instants.append(simulator.step())
    best = float("inf")
    for _ in range(repeats):
        bubbles = Bubbles(SETTINGS[setting])
        start = time.thread_time()
        for inst in instants:
            feats = bubbles.frame(inst, spec.scene)
            for side in SIDES:
                estimate(feats[side], side, cal, "physics")
        best = min(best, (time.thread_time() - start) / len(instants))
    return best


def wrench_rows(
    world: str, cal_recs: list[Recorded], test_recs: list[Recorded], secs: dict[str, float]
) -> tuple[list[Row], dict[str, Calibration]]:
    """Each setting's calibration on ``cal_recs``, each method scored on ``test_recs``."""
    rows: list[Row] = []
    cals: dict[str, Calibration] = {}
    for setting in SETTINGS:
        data = []
        for k, rec in enumerate(cal_recs):
            frames = [
                dataclasses.replace(f, features=feats)
                for f, feats in zip(rec.frames, rec.by_setting[setting], strict=True)
            ]
            data += samples(frames, k)
        cal = calibrate(data, rig=world, source="bench.force")
        cals[setting] = cal
        # The dots against the object's slide: world.sim's truth (MuJoCo's has none).
        shift_err = [
            e for rec in test_recs if world == "sim"
            for e in shift_errors_m(rec.frames, rec.by_setting[setting])
        ]  # fmt: skip
        for method in METHODS:
            ferr, terr, pct, within = [], [], [], []
            for rec in test_recs:
                for f, feats in zip(rec.frames, rec.by_setting[setting], strict=True):
                    for side in SIDES:
                        if not (feats[side].in_contact and np.any(f.force_n[side]) and held(f)):
                            continue
                        w = estimate(feats[side], side, cal, method)
                        e = float(np.linalg.norm(w.force_n - f.force_n[side]))
                        load = float(np.linalg.norm(f.force_n[side]))
                        ferr.append(e)
                        terr.append(float(np.linalg.norm(w.torque_nm - f.torque_nm[side])))
                        pct.append(100.0 * e / load)
                        within.append(e <= max(GOAL_FRACTION * load, GOAL_N))
            rows.append(
                {
                    "sweep": "wrench",
                    "world": world,
                    "setting": setting,
                    "method": method,
                    "samples": len(ferr),
                    "force_err_n_median": median(ferr),
                    "force_err_n_p90": percentile(ferr, 90),
                    "force_err_pct_median": median(pct),
                    "torque_err_nm_median": median(terr),
                    "torque_err_nm_p90": percentile(terr, 90),
                    "within_goal_fraction": float(np.mean(within)) if within else float("nan"),
                    "shift_err_mm_median": median(shift_err) * 1000.0,
                    "ms_per_frame": secs[setting] * 1000.0,
                    "rate_hz": 1.0 / secs[setting],
                }
            )
    return rows, cals


def first(flags: list[bool]) -> int | None:
    return next((i for i, f in enumerate(flags) if f), None)


def slip_rows(
    world: str,
    test_recs: list[Recorded],
    cal: Calibration,
    period_secs: float,
    params: SlipParams | None = None,
) -> list[Row]:
    """Onsets against the truth's, and false alarms while held still (module docstring)."""
    found: dict[str, list[float]] = {"edge": [], "patch": []}
    missed = {"edge": 0, "patch": 0}
    cut = {"edge": 0, "patch": 0}
    false_alarms, still_secs = 0, 0.0
    for rec in test_recs:
        for side in SIDES:
            detector = SlipDetector.for_rig(cal, params)
            onsets: dict[str, int] = {}
            stable, start = False, None
            for i, f in enumerate(rec.frames):
                feats = f.features[side]
                # The slip node's reference: the grasp monitor's stable grasp (what
                # moved before it, the jaws closing and the hand letting go, is not slip).
                if f.stable and not stable:
                    detector.reference()
                    start = i if start is None else start
                elif stable and not f.stable:
                    detector.drop()
                stable = f.stable
                w = estimate(feats, side, cal, "physics")
                report = detector.update(feats, w.force_n, f.t_secs)
                truth_now = f.slipping[side]
                soon = [g.slipping[side] for g in rec.frames[i : i + MAX_EARLY_FRAMES]]
                if report.onset:
                    onsets.setdefault(report.onset, i)
                    if max(soon) == 0.0:
                        false_alarms += 1
                if stable and max(soon) == 0.0 and truth_now == 0.0:
                    still_secs += period_secs
            if start is None:
                continue  # never held: nothing to score
            # The truth's onsets from the reference on (a patch still slipping from
            # before it starts no onset there).
            truth = {
                "edge": first([i >= start and f.slipping[side] > 0.0
                               and rec.frames[i - 1].slipping[side] == 0.0
                               for i, f in enumerate(rec.frames)]),
                "patch": first([i >= start and f.slipping[side] >= 1.0
                                and rec.frames[i - 1].slipping[side] < 1.0
                                for i, f in enumerate(rec.frames)]),
            }  # fmt: skip
            for phase in ("edge", "patch"):
                if truth[phase] is None:
                    continue
                if len(rec.frames) - truth[phase] < MIN_SCORED_FRAMES:
                    cut[phase] += 1  # the recording ends before a detector could tell
                    continue
                # The edge's onset is the first of either (a whole patch sliding has
                # its edge slipping too); the whole patch's, the patch onset.
                got = [onsets[p] for p in (("edge", "patch") if phase == "edge" else ("patch",))
                       if p in onsets]  # fmt: skip
                lag = min(got) - truth[phase] if got else None
                if lag is not None and -MAX_EARLY_FRAMES <= lag <= MAX_LATE_FRAMES:
                    found[phase].append(float(lag))
                else:
                    missed[phase] += 1
    rows: list[Row] = []
    cue = (params or SlipParams()).edge_cue
    for phase in ("edge", "patch"):
        lags = found[phase]
        total = len(lags) + missed[phase]
        rows.append(
            {
                "sweep": "slip",
                "world": world,
                "setting": DEFAULT_SETTING,
                "method": f"onset_{phase}" + ("" if cue == "both" else f"_{cue}"),
                "samples": total,
                "cut_at_end": cut[phase],
                "detected_fraction": len(lags) / total if total else float("nan"),
                "onset_frames_median": median(lags),
                "onset_ms_median": median(lags) * period_secs * 1000.0,
                "onset_frames_max": max(lags) if lags else float("nan"),
                "false_alarms_per_min": false_alarms / (still_secs / 60.0)
                if still_secs
                else float("nan"),
                "still_secs": still_secs,
            }
        )
    return rows


@dataclass(frozen=True)
class Sizes:
    """How much each sweep runs (the default run; ``--quick`` and the flags change it)."""

    grasps: int = 8  # world.sim grasps per set (calibration, held out)
    duration_secs: float = 3.0
    mujoco: int = 8  # MuJoCo grasps (half calibration, half held out)
    mujoco_mesh_m: float = 0.008
    slides: int = 8  # MuJoCo loaded grasps, a free object (half calibration)
    still: int = 4  # still holds of 15 s for the false alarms (MuJoCo: 6 s)
    still_secs: float = 15.0
    mujoco_still_secs: float = 6.0
    loaded_secs: float = 3.0  # MuJoCo's loaded grasps (the load from 1 s)
    reflex: int = 8
    mujoco_reflex: int = 4
    handover: int = 4
    timing_repeats: int = TIMING_REPEATS


QUICK = Sizes(
    grasps=2, duration_secs=1.8, mujoco=1, mujoco_mesh_m=0.012, slides=1, still=1,
    still_secs=3.0, mujoco_still_secs=1.5, loaded_secs=2.0, reflex=1, mujoco_reflex=1, handover=1,
    timing_repeats=1,
)  # fmt: skip


SWEEPS = ("wrench", "slip", "reflex", "handover")


def run(quick: bool, sizes: Sizes | None = None, sweeps: tuple[str, ...] = SWEEPS) -> list[Row]:
    """Every sweep in ``sweeps`` (the module docstring); without ``wrench`` only the
    default flow setting's features are computed (the others serve the wrench sweep)."""
    one_core()
    z = QUICK if quick else (sizes or Sizes())
    n, duration = z.grasps, z.duration_secs
    settings = () if "wrench" in sweeps else (DEFAULT_SETTING,)
    cal_seeds, test_seeds = list(range(n)), list(range(n, 2 * n))
    cal_recs = [
        record_all(s, duration, settings=settings)
        for s in progress(cal_seeds, "bench.force calibration")
    ]
    test_recs = [
        record_all(s, duration, settings=settings)
        for s in progress(test_seeds, "bench.force held-out")
    ]
    rows: list[Row] = []
    if "wrench" in sweeps:
        placeholder = calibrate(
            [s for k, rec in enumerate(cal_recs) for s in samples(rec.frames, k)],
            rig="sim",
            source="timing",
        )
        secs = {
            setting: time_setting(
                test_seeds[0], 1.2 if quick else 2.0, setting, placeholder, z.timing_repeats
            )
            for setting in progress(list(SETTINGS), "bench.force timing")
        }
        rows, cals = wrench_rows("sim", cal_recs, test_recs, secs)
        cal = cals[DEFAULT_SETTING]
    else:
        cal = calibrate(
            [s for k, rec in enumerate(cal_recs) for s in samples(rec.frames, k)],
            rig="sim",
            source="bench.force",
        )
    # The second world: the engine's contact forces, calibrated on its own grasps.
    # (--quick: one grasp, scored on itself: a smoke test, not held out.)
    # Its slips: loaded grasps of a free object (filled, pulled past the stick limit),
    # half to calibrate the slip limits (with the calibration grasps), half scored; and
    # still holds. (--quick: one loaded grasp, scored on itself.)
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp) if quick else Path(os.environ.get("WORLDS_DIR", "out/worlds"))
        workdir.mkdir(parents=True, exist_ok=True)
        recs = force_mujoco.grasps(z.mujoco, z.mujoco_mesh_m, workdir, settings)
        slides = force_mujoco.loaded(
            z.slides, z.mujoco_mesh_m, workdir, duration_secs=z.loaded_secs, settings=settings
        )
        mujoco_still = force_mujoco.loaded(
            z.still, z.mujoco_mesh_m, workdir, duration_secs=z.mujoco_still_secs, still=True
        )
    half = max(1, z.mujoco // 2)
    period = draw(0).scene.frame_period_secs
    cut = max(1, z.slides // 2)
    mujoco_cal = force_mujoco.calibrate_mujoco(recs[:half], slides[:cut], "bench.force")
    if "wrench" in sweeps:
        rows += wrench_rows("mujoco", recs[:half], recs[half:] or recs, secs)[0]
        # The force on the loaded grasps held out (loads along tool y and z).
        rows += wrench_rows(
            "mujoco_loaded", recs[:half] + slides[:cut], slides[cut:] or slides, secs
        )[0]
    if "slip" in sweeps:
        # Long still holds for the false alarms (the default setting only).
        still = [
            record_all(100 + i, z.still_secs, load="still", settings=(DEFAULT_SETTING,))
            for i in progress(range(z.still), "bench.force still holds")
        ]
        # The edge cues side by side: both (the default), the stick limit, the dots
        # leaving the rigid motion.
        for cue in EDGE_CUES:
            params = SlipParams(edge_cue=cue)
            rows += slip_rows("sim", test_recs + still, cal, period, params)
            rows += slip_rows(
                "mujoco", (slides[cut:] or slides) + mujoco_still, mujoco_cal, period, params
            )
    if "reflex" in sweeps:
        reflex_seeds = [n * 2 + i for i in range(z.reflex)]
        rows += reflex_rows(reflex_seeds, 2.5 if quick else 4.0, cal)
        rows += reflex_rows(
            force_mujoco.reflex_seeds(z.mujoco_reflex), 2.5 if quick else 4.0, mujoco_cal,
            z.mujoco_mesh_m,
        )  # fmt: skip
    if "handover" in sweeps:
        rows += handover_rows(list(range(z.handover)), cal, period)
    return rows


COLUMNS = [
    "sweep", "world", "setting", "method", "samples", "force_err_n_median", "force_err_pct_median",
    "torque_err_nm_median", "within_goal_fraction", "shift_err_mm_median", "ms_per_frame",
    "rate_hz",
    "detected_fraction", "onset_frames_median", "onset_ms_median", "false_alarms_per_min",
    "kept", "dropped", "dropped_at_bound", "saved_fraction", "saved_within_bound_fraction",
    "release_latency_ms_median", "false_release_rate",
]  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--grasps", type=int, default=Sizes.grasps, help="sim grasps per set")
    parser.add_argument("--mujoco", type=int, default=Sizes.mujoco, help="MuJoCo grasps")
    parser.add_argument("--slides", type=int, default=Sizes.slides, help="MuJoCo slides")
    parser.add_argument("--still", type=int, default=Sizes.still, help="15 s still holds")
    parser.add_argument("--reflex", type=int, default=Sizes.reflex, help="reflex grasps")
    parser.add_argument(
        "--mujoco-reflex", type=int, default=Sizes.mujoco_reflex, help="MuJoCo reflex grasps"
    )
    parser.add_argument("--handover", type=int, default=Sizes.handover, help="handovers")
    parser.add_argument(
        "--mujoco-mesh", type=float, default=Sizes.mujoco_mesh_m, help="MuJoCo mesh edge, m"
    )
    parser.add_argument(
        "--sweeps", default=",".join(SWEEPS), help=f"comma-separated, of {','.join(SWEEPS)}"
    )
    extra, rest = parser.parse_known_args()
    sweeps = tuple(extra.sweeps.split(","))
    if not sweeps or set(sweeps) - set(SWEEPS):
        sys.exit(f"bench.force: --sweeps takes some of {','.join(SWEEPS)}, got {extra.sweeps!r}")
    counts = (
        *(extra.grasps, extra.mujoco, extra.slides, extra.still, extra.reflex),
        *(extra.mujoco_reflex, extra.handover),
    )
    if min(extra.grasps, extra.mujoco, extra.slides) < 2 or min(counts) < 1:
        sys.exit(
            f"bench.force: --grasps, --mujoco and --slides must be >= 2, the rest >= 1, got {extra}"
        )
    chosen = Sizes(
        grasps=extra.grasps,
        mujoco=extra.mujoco,
        slides=extra.slides,
        still=extra.still,
        reflex=extra.reflex,
        mujoco_reflex=extra.mujoco_reflex,
        handover=extra.handover,
        mujoco_mesh_m=extra.mujoco_mesh,
    )
    main("force", lambda quick: run(quick, chosen, sweeps), columns=COLUMNS, argv=rest)
