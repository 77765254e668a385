"""The auto-labelling grasp generator: deterministic, balanced, feasible."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from geometry import objects
from geometry.gripper import DEFAULT_GRIPPER
from geometry.se3 import invert
from perception.classify.autolabel import GraspGenerator, GraspGeneratorParams, end_distance_m
from runtime.params import build_params


@pytest.fixture(scope="module")
def grasps():
    generator = GraspGenerator(GraspGeneratorParams(seed=11))
    return generator, [generator.sample(i) for i in range(24)]


def test_deterministic_per_seed_and_grasp(grasps) -> None:
    generator, samples = grasps
    again = GraspGenerator(GraspGeneratorParams(seed=11)).sample(17)
    assert np.array_equal(again.tool_from_object, samples[17].tool_from_object)
    assert again.to_params() == samples[17].to_params()
    other = GraspGenerator(GraspGeneratorParams(seed=12)).sample(17)
    assert not np.allclose(other.tool_from_object, samples[17].tool_from_object)


def test_classes_are_balanced_in_blocks(grasps) -> None:
    _, samples = grasps
    counts = Counter(s.object_name for s in samples)
    assert counts == {name: 6 for name in objects.NAMES}
    for block in range(6):
        names = {s.object_name for s in samples[4 * block : 4 * block + 4]}
        assert names == set(objects.NAMES)


def test_grasps_fit_the_gripper_and_touch_both_bubbles(grasps) -> None:
    _, samples = grasps
    g = DEFAULT_GRIPPER
    for s in samples:
        assert 0 < s.grasp_width_m < s.contact_width_m <= g.max_width_m
        rot = s.tool_from_object[:3, :3]
        assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-9)
        # The grasp point on the object's axis sits between the jaws, near the tool origin.
        axis_point = s.tool_from_object @ np.array([0.0, 0.0, s.height_m, 1.0])
        assert np.all(np.abs(axis_point[:3]) < 0.05)
        # At the contact opening each bubble's apex region just reaches the object: the
        # object's surface lies within the jaws' span, and crosses tool x = 0.
        model = objects.make(s.object_name)
        pts = model.sample_surface(2000, np.random.default_rng(0))
        in_tool = pts @ rot.T + s.tool_from_object[:3, 3]
        assert in_tool[:, 0].min() < 0 < in_tool[:, 0].max()
        assert np.allclose(invert(invert(s.tool_from_object)), s.tool_from_object)


def test_heights_spread_along_the_objects(grasps) -> None:
    _, samples = grasps
    for name in objects.NAMES:
        lo, hi = objects.make(name).bounds_m()
        heights = [s.height_m for s in samples if s.object_name == name]
        assert all(lo[2] < h < hi[2] for h in heights)
        assert np.ptp(heights) > 0.2 * (hi[2] - lo[2])


def test_end_fraction_draws_near_the_ends_and_zero_changes_nothing(grasps) -> None:
    _, samples = grasps
    plain = GraspGenerator(GraspGeneratorParams(seed=11, end_fraction=0.0))
    assert plain.sample(5).to_params() == samples[5].to_params()
    ends = GraspGenerator(GraspGeneratorParams(seed=11, end_fraction=1.0, end_band_m=0.02))
    drawn = [ends.sample(i) for i in range(24)]
    near = [end_distance_m(s.object_name, s.height_m) for s in drawn]
    assert all(0.006 <= d <= 0.02 for d in near)
    spread = [end_distance_m(s.object_name, s.height_m) for s in samples]
    assert np.median(spread) > 0.03  # the plain generator's grasps are mostly on the body
    # Both ends are drawn: heights below and above the object's middle.
    heights = [s.height_m for s in drawn]
    assert min(heights) < 0 < max(heights)


def test_bad_params_and_impossible_grasps() -> None:
    with pytest.raises(ValueError, match="objects"):
        build_params(GraspGeneratorParams, {"objects": ("teapot",)})
    with pytest.raises(ValueError, match="squeeze_max_m"):
        build_params(GraspGeneratorParams, {"squeeze_min_m": 0.01, "squeeze_max_m": 0.005})
    with pytest.raises(ValueError, match="end_fraction"):
        build_params(GraspGeneratorParams, {"end_fraction": 1.5})
    with pytest.raises(ValueError, match="end_band_m"):
        build_params(GraspGeneratorParams, {"end_band_m": 0.004})
    with pytest.raises(ValueError, match="grasp_id"):
        GraspGenerator(GraspGeneratorParams()).sample(-1)
    # A clearance larger than the stroke leaves no feasible grasp: a clear error.
    tight = GraspGenerator(GraspGeneratorParams(clearance_m=0.2, max_tries=5))
    with pytest.raises(ValueError, match="no feasible grasp"):
        tight.sample(0)
