"""Scene files: every shipped scene loads; bad fields are named in the error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.scene import SceneError, load_scene, scene_from_dict
from tests.sim.conftest import make_scene

SCENES = sorted(Path("scenes").glob("*.yaml"))


def test_scene_files_exist_for_every_object_class() -> None:
    names = {load_scene(p).object.name for p in SCENES}
    assert {"mug", "pet_bottle", "square_bottle", "wine_glass"} <= names
    assert any(load_scene(p).effects == ("membrane", "depth") for p in SCENES)


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_shipped_scene_loads(path: Path) -> None:
    scene = load_scene(path)
    assert scene.frame_count > 1
    pose = scene.tool_from_object(scene.duration_secs / 2)
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize(
    "change,match",
    [
        ({"effects": ["membrane", "lasers"]}, "effects.*lasers"),
        ({"camera": {"width_px": -3}}, "camera.*width_px"),
        ({"gripper": {"commands": [{"t_secs": 0, "command": "dance"}]}}, r"commands\[0\].*command"),
        ({"bubble": {"colour": "red"}}, "bubble.*colour"),
        ({"object": {"name": "teapot"}}, "object.*teapot"),
        ({"trajectory": [{"t_secs": 1.0}, {"t_secs": 0.5}]}, "trajectory.*increase"),
        ({"pattern": {"randomness": 2.0}}, "pattern.*randomness"),
        ({"flavour": 1}, "flavour"),
    ],
)
def test_bad_scene_names_the_field(change: dict, match: str) -> None:
    with pytest.raises(SceneError, match=match):
        make_scene(**change)


def test_missing_object_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="object"):
        scene_from_dict({"name": "x"}, path="x.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(SceneError, match="bad.yaml"):
        load_scene(bad)


def test_trajectory_interpolates_translation_and_rotation() -> None:
    scene = make_scene(
        mount_rpy_deg=[0, 0, 0],
        trajectory=[
            {"t_secs": 0.0, "xyz_m": [0, 0, 0], "rpy_deg": [0, 0, 0]},
            {"t_secs": 1.0, "xyz_m": [0, 0.01, 0], "rpy_deg": [20, 0, 0]},
        ],
    )
    mid = scene.tool_from_object(0.5)
    np.testing.assert_allclose(mid[:3, 3], [0, 0.005, 0])
    angle = np.degrees(np.arctan2(mid[2, 1], mid[1, 1]))
    assert angle == pytest.approx(10.0)
    np.testing.assert_allclose(scene.tool_from_object(5.0), scene.tool_from_object(1.0))
