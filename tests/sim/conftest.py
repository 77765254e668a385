"""Shared helpers for the simulator tests: small scenes built in code."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sim.scene import Scene, scene_from_dict

# Object axis along tool y, mug handle along tool z (as in scenes/*.yaml).
MOUNT = [0, -90, -90]


def make_scene(**fields: Any) -> Scene:
    """A mug scene with defaults, overridable per top-level field."""
    data: dict[str, Any] = {
        "name": "test",
        "seed": 3,
        "duration_secs": 0.5,
        "object": {"name": "mug"},
        "mount_rpy_deg": MOUNT,
        "trajectory": [{"t_secs": 0.0, "xyz_m": [0.0, 0.0, 0.005]}],
        "effects": ["membrane", "depth"],
    }
    data.update(fields)
    return scene_from_dict(data, path="<test>")


def held_pose(x: float = 0.0, y: float = 0.0, z: float = 0.005) -> np.ndarray:
    return make_scene(trajectory=[{"t_secs": 0.0, "xyz_m": [x, y, z]}]).tool_from_object(0.0)


@pytest.fixture
def mug_scene() -> Scene:
    return make_scene()
