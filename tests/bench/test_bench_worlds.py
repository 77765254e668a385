"""``python -m bench.worlds --quick``: one grasp on both worlds, every figure present."""

from __future__ import annotations

import math

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
        assert row["grasps"] == 1
        for key in (
            "contact_iou_median",
            "lm_axis_deg_median",
            "ipopt_axis_deg_median",
            "shear_dir_deg_median",
            "world_cpu_s_per_sim_s",
        ):
            assert math.isfinite(row[key]), (row["world"], key)
        assert 0.0 <= row["contact_iou_median"] <= 1.0
        assert row["stable_detected_fraction"] in (0.0, 1.0)
        assert row["classifier_drawn_right_fraction"] in (0.0, 1.0)
    # The engine costs what it costs: far more than the geometric world, but finite.
    assert rows["mujoco"]["world_cpu_s_per_sim_s"] > rows["sim"]["world_cpu_s_per_sim_s"]
    # A mug grasped in the middle is seen as a contact patch on both worlds.
    assert rows["mujoco"]["contact_iou_median"] > 0.3


def test_drawn_grasps_are_the_auto_labellers_grasps() -> None:
    # The classifier's own grasps: the generator's pose, width and force, as a scene.
    from bench.worlds import DRAWN_SEED, drawn_scene
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
    from bench.worlds import DRAWN_SEED, drawn_scene
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
