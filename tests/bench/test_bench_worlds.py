"""``python -m bench.worlds --quick``: one grasp on both worlds, every figure present;
with ``--variants held_out``, the classifier's drawn grasp alone."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tests.bench import run_quick


def test_worlds_quick_scores_one_grasp_on_both_worlds() -> None:
    report, _ = run_quick("worlds", "--no-plot", timeout=600)
    rows = {r["world"]: r for r in report["rows"]}
    assert set(rows) == {"sim", "mujoco", "mujoco (cost)"}
    cost = rows.pop("mujoco (cost)")
    assert cost["mesh_mm"] == 12.0 and cost["vertices_per_bubble"] > 30
    assert math.isfinite(cost["world_cpu_s_per_sim_s"]) and cost["world_cpu_s_per_sim_s"] > 0
    for row in rows.values():
        assert row["grasps"] == 1 and row["drawn_grasps"] == 1 and row["variants"] == "none"
        for key in (
            "contact_iou_median",
            "lm_axis_deg_median",
            "lm_offaxis_mm_median",
            "ipopt_axis_deg_median",
            "ipopt_offaxis_mm_median",
            "shear_dir_deg_median",
            "shear_err_mm_median",
            "shear_warm_dir_deg_median",
            "shear_warm_err_mm_median",
            "world_cpu_s_per_sim_s",
        ):
            assert math.isfinite(row[key]), (row["world"], key)
        assert 0.0 <= row["contact_iou_median"] <= 1.0
        assert row["pose_silent_wrong"] in (0, 1, 2)  # of one grasp's two answers
        assert row["stable_detected_fraction"] in (0.0, 1.0)
        if row["stable_detected_fraction"]:
            assert math.isfinite(row["stable_delay_s_median"]), row["world"]
        # Both classifier rows counted: a wrong answer is listed, a right one is not.
        for right, wrong in (
            ("classifier_right_fraction", "classifier_wrong"),
            ("classifier_drawn_right_fraction", "classifier_drawn_wrong"),
        ):
            assert row[right] in (0.0, 1.0), (row["world"], right)
            assert (row[wrong] == "") == (row[right] == 1.0), (row["world"], row[wrong])
    assert rows["sim"]["mesh_mm"] is None and rows["mujoco"]["mesh_mm"] == 12.0
    # The engine costs what it costs: far more than the geometric world, but finite.
    assert rows["mujoco"]["world_cpu_s_per_sim_s"] > rows["sim"]["world_cpu_s_per_sim_s"]
    # A mug grasped in the middle is seen as a contact patch on both worlds.
    assert rows["mujoco"]["contact_iou_median"] > 0.3


def test_worlds_quick_held_out_variants_scores_the_drawn_grasps_alone() -> None:
    report, _ = run_quick("worlds", "--no-plot", "--variants", "held_out", timeout=600)
    rows = {r["world"]: r for r in report["rows"]}
    # Only the classifier's drawn grasps: no bench grasps, no cost rows.
    assert set(rows) == {"sim", "mujoco"}
    for row in rows.values():
        assert row["variants"] == "held_out" and row["drawn_grasps"] == 1
        assert "grasps" not in row and "contact_iou_median" not in row
        assert row["classifier_drawn_right_fraction"] in (0.0, 1.0)
        right = row["classifier_drawn_right_fraction"] == 1.0
        assert (row["classifier_drawn_wrong"] == "") == right, row["classifier_drawn_wrong"]
    assert rows["sim"]["mesh_mm"] is None and rows["mujoco"]["mesh_mm"] == 12.0


def test_drawn_grasps_are_the_auto_labellers_grasps() -> None:
    # The classifier's own grasps: the generator's pose, width and force, as a scene.
    from bench.worlds_grasps import DRAWN_SEED, drawn_scene
    from perception.classify.autolabel import GraspGenerator, GraspGeneratorParams
    from sim.scene import scene_from_dict

    generator = GraspGenerator(GraspGeneratorParams(seed=DRAWN_SEED))
    for k in range(4):
        sample = generator.sample(k)
        scene = scene_from_dict(drawn_scene(k))
        assert scene.object.name == sample.object_name
        assert np.allclose(scene.tool_from_object(0.0), sample.tool_from_object, atol=1e-9)
        (command,) = scene.gripper.commands
        assert command.width_m == sample.grasp_width_m and command.force_n == sample.force_n
        assert "dot_pattern" not in scene.resolved_effects


def test_drawn_grasps_hold_held_out_variants_when_asked() -> None:
    from bench.worlds_grasps import DRAWN_SEED, drawn_scene
    from geometry.variants import SPLITS, variant_dims
    from perception.classify.autolabel import GraspGenerator, GraspGeneratorParams
    from sim.scene import scene_from_dict

    generator = GraspGenerator(GraspGeneratorParams(seed=DRAWN_SEED, variants="held_out"))
    for k in range(4):
        sample = generator.sample(k)
        scene = scene_from_dict(drawn_scene(k, "held_out"))
        assert scene.object.variant == sample.variant and sample.variant in SPLITS["held_out"]
        assert dict(scene.object.dims_m) == variant_dims(sample.object_name, sample.variant)
        assert np.allclose(scene.tool_from_object(0.0), sample.tool_from_object, atol=1e-9)
    assert scene_from_dict(drawn_scene(0)).object.variant is None


def _scores(
    name: str, said: str, *, lm_wrong: int, ipopt_wrong: int, delay: float
) -> dict[str, Any]:
    # One grasp's scores as bench.worlds.score gives them (the figures made up).
    return {
        "object": name,
        "contact_iou": 0.7,
        "lm_axis_deg": 0.4,
        "lm_offaxis_mm": 0.5,
        "lm_silent_wrong": lm_wrong,
        "ipopt_axis_deg": 0.5,
        "ipopt_offaxis_mm": 0.6,
        "ipopt_silent_wrong": ipopt_wrong,
        "shear_dir_deg": 2.0,
        "shear_err_mm": 0.7,
        "shear_warm_dir_deg": 1.0,
        "shear_warm_err_mm": 0.3,
        "stable_detected": int(delay == delay),
        "stable_delay_s": delay,
        "classifier_said": said,
        "classifier_right": int(said == name),
    }


def test_the_summary_counts_every_grasp_and_both_solvers() -> None:
    from bench.worlds import _summary

    scores = [
        _scores("mug", "mug", lm_wrong=0, ipopt_wrong=1, delay=0.3),
        _scores("pet_bottle", "mug", lm_wrong=1, ipopt_wrong=1, delay=float("nan")),
        _scores("square_bottle", "square_bottle", lm_wrong=0, ipopt_wrong=0, delay=0.5),
        _scores("wine_glass", "mug", lm_wrong=0, ipopt_wrong=0, delay=0.2),
    ]
    scores[1]["lm_axis_deg"] = 9.0  # a median is not moved by one grasp far off
    drawn = [
        {"drawn_object": "mug", "drawn_said": "mug", "classifier_drawn_right": 1},
        {"drawn_object": "wine_glass", "drawn_said": "not stable", "classifier_drawn_right": 0},
    ]
    row = _summary("mujoco", scores, [8.0, 9.0, 10.0, 30.0], drawn)
    assert row["world"] == "mujoco" and row["grasps"] == 4
    # Every answer wrong and marked ok, of both solvers on every grasp.
    assert row["pose_silent_wrong"] == 3
    assert row["lm_axis_deg_median"] == 0.4
    assert row["stable_detected_fraction"] == 0.75
    assert row["stable_delay_s_median"] == 0.3  # of the grasps found stable
    assert row["classifier_right_fraction"] == 0.5
    assert row["classifier_wrong"] == "pet_bottle->mug wine_glass->mug"
    assert row["drawn_grasps"] == 2 and row["classifier_drawn_right_fraction"] == 0.5
    assert row["classifier_drawn_wrong"] == "wine_glass->not stable"
    assert row["world_cpu_s_per_sim_s"] == 9.5
