"""Object variant families: deterministic, spanning their documented ranges, valid shapes,
and drawn by the auto-labeller only from the split it is asked for."""

from __future__ import annotations

import numpy as np
import pytest

from geometry import objects, variants
from perception.classify.autolabel import GraspGenerator, GraspGeneratorParams
from sim.scene import SceneError, scene_from_dict

TRAIN = variants.SPLITS["train"]
HELD_OUT = variants.SPLITS["held_out"]


def test_splits_are_disjoint_and_every_class_has_a_family() -> None:
    assert not set(TRAIN) & set(HELD_OUT)
    assert set(variants.FAMILIES) == set(objects.NAMES)
    assert variants.split_of(TRAIN[0]) == "train"
    assert variants.split_of(HELD_OUT[-1]) == "held_out"
    with pytest.raises(ValueError, match="in no split"):
        variants.variant_dims("mug", HELD_OUT.stop)
    with pytest.raises(ValueError, match="no variant family"):
        variants.variant_dims("teapot", 0)


@pytest.mark.parametrize("name", sorted(variants.FAMILIES))
def test_a_variant_is_the_same_shape_every_time_and_variants_differ(name: str) -> None:
    assert variants.variant_dims(name, 1003) == variants.variant_dims(name, 1003)
    assert variants.variant_dims(name, 1003) != variants.variant_dims(name, 1004)
    assert variants.variant_dims(name, 3) != variants.variant_dims(name, 1003)


@pytest.mark.parametrize("name", sorted(variants.FAMILIES))
def test_draws_span_the_documented_ranges(name: str) -> None:
    draws = [variants.draw(name, v) for v in list(TRAIN[:150]) + list(HELD_OUT[:150])]
    for key, (lo, hi) in variants.FAMILIES[name].ranges.items():
        values = np.array([d[key] for d in draws])
        assert np.all((values >= lo) & (values <= hi)), key
        # 300 uniform draws: both ends of the range are reached within a tenth of it.
        assert values.min() < lo + 0.1 * (hi - lo), key
        assert values.max() > hi - 0.1 * (hi - lo), key


@pytest.mark.parametrize("name", sorted(variants.FAMILIES))
def test_variants_are_valid_closed_shapes(name: str) -> None:
    rng = np.random.default_rng(0)
    for v in list(TRAIN[:12]) + list(HELD_OUT[:12]):
        model = variants.make_variant(name, v)
        lo, hi = model.bounds_m()
        assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)
        # On the surface the field is zero; inside (on the axis) negative; on a box 1 cm
        # beyond the bounds positive everywhere: a closed solid.
        surface = model.sample_surface(400, rng)
        assert np.all(np.isfinite(surface))
        assert np.max(np.abs(model.field.value(surface))) < 1e-6
        axis = np.stack([np.zeros(20), np.zeros(20), np.linspace(lo[2], hi[2], 22)[1:-1]], 1)
        assert np.all(model.field.value(axis) < 0.0)
        box = rng.uniform(lo - 0.01, hi + 0.01, size=(2000, 3))
        face = rng.integers(3, size=len(box))
        box[np.arange(len(box)), face] = np.where(
            rng.uniform(size=len(box)) < 0.5, lo[face] - 0.01, hi[face] + 0.01
        )
        outside = model.field.value(box)
        assert np.all(np.isfinite(outside)) and np.all(outside > 0.0)
        if name == "mug":  # the handle stays on the body, both ends
            d = model.dims_m
            top = abs(d["handle_offset_m"]) + d["handle_span_m"] / 2 + d["handle_radius_m"]
            assert top <= d["height_m"] / 2 + 1e-12


def _variants_drawn(split: str) -> list[int | None]:
    generator = GraspGenerator(GraspGeneratorParams(seed=5, variants=split))
    return [generator.sample(i).variant for i in range(16)]


def test_the_autolabeller_draws_held_out_variants_only_when_asked() -> None:
    assert _variants_drawn("none") == [None] * 16
    train = _variants_drawn("train")
    assert all(v in TRAIN for v in train) and len(set(train)) > 8
    held = _variants_drawn("held_out")
    assert all(v in HELD_OUT for v in held) and len(set(held)) > 8
    # The variant has its own stream: the objects and their order are the same.
    plain = GraspGenerator(GraspGeneratorParams(seed=5))
    drawn = GraspGenerator(GraspGeneratorParams(seed=5, variants="held_out"))
    assert [plain.object_for(i) for i in range(16)] == [drawn.object_for(i) for i in range(16)]
    sample = drawn.sample(3)
    assert sample.to_params()["variant"] == sample.variant
    assert "variant" not in plain.sample(3).to_params()
    with pytest.raises(ValueError, match="variants"):
        GraspGeneratorParams(variants="test")


def test_a_scene_names_a_variant() -> None:
    scene = scene_from_dict({"object": {"name": "wine_glass", "variant": 1007}}, path="s.yaml")
    assert dict(scene.object.dims_m) == variants.variant_dims("wine_glass", 1007)
    over = scene_from_dict(
        {"object": {"name": "mug", "variant": 3, "dims_m": {"radius_m": 0.041}}}, path="s.yaml"
    )
    assert over.object.model().dims_m["radius_m"] == 0.041
    assert over.object.model().dims_m["height_m"] == variants.variant_dims("mug", 3)["height_m"]
    with pytest.raises(SceneError, match=r"s\.yaml: object: variant 5000 is in no split"):
        scene_from_dict({"object": {"name": "mug", "variant": 5000}}, path="s.yaml")
    with pytest.raises(SceneError, match=r"s\.yaml: object\.variant: expected an integer"):
        scene_from_dict({"object": {"name": "mug", "variant": "big"}}, path="s.yaml")
