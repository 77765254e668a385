"""Effects: resolution over needs, and an effect that is off is neither output nor paid."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from sim import tof as render_module
from sim.effects import ALL_EFFECTS, EFFECTS, resolve
from tests.sim.conftest import held_pose, make_scene


def test_resolve_closes_over_needs_in_run_order() -> None:
    assert resolve(["depth"]) == ("membrane", "depth")
    assert resolve(["tof_noise"]) == ("membrane", "depth", "ir", "tof_noise")
    assert resolve(["dot_pattern"]) == ("membrane", "ir", "dot_pattern")
    assert resolve(["gripper"]) == ("pressure", "gripper")
    assert resolve(ALL_EFFECTS) == ALL_EFFECTS
    for name, effect in EFFECTS.items():
        for need in effect.needs:
            assert ALL_EFFECTS.index(need) < ALL_EFFECTS.index(name)


def test_unknown_effect_lists_valid_ones() -> None:
    with pytest.raises(ValueError, match="unknown effect 'smell'.*membrane"):
        resolve(["membrane", "smell"])


def _explode(*args: object, **kwargs: object) -> None:
    raise AssertionError("an effect that is off was evaluated")


def test_minimal_scene_does_not_evaluate_ir_dots_shear(monkeypatch: pytest.MonkeyPatch) -> None:
    for step in ("ir", "dot_pattern", "shear", "tof_noise"):
        monkeypatch.setitem(render_module._STEPS, step, _explode)
    monkeypatch.setattr(render_module.BubbleRenderer, "texture", _explode)
    scene = make_scene(effects=["membrane", "depth"])
    simulator = sim.Simulator(scene)
    for _ in range(3):
        instant = simulator.step()
    for renderer in simulator.renderers.values():
        assert set(renderer.calls) == {"membrane", "depth"}
        assert renderer.calls["membrane"] == 3
    left = instant.images["left"]
    assert left.depth_m.shape == (172, 224)
    assert left.ir.shape == (0, 0)
    assert instant.pressures == {} and instant.ground_truth is None and instant.masks == {}
    assert "albedo" not in instant.frames["left"].arrays
    assert "material_shift_m" not in instant.frames["left"].arrays


def test_all_effects_are_evaluated_and_output() -> None:
    inst = sim.render_grasp("mug", held_pose(), 0.065, effects=ALL_EFFECTS)
    arrays = inst.frames["left"].arrays
    for key in ("range_m", "depth_m", "amplitude", "albedo", "material_shift_m", "invalid"):
        assert key in arrays
    assert inst.images["left"].ir.shape == (172, 224)
    assert inst.images["left"].ir.dtype == np.uint16
    assert set(inst.pressures) == {"left", "right"}
    assert inst.ground_truth is not None and inst.ground_truth.in_contact
    assert inst.masks["left"].mask.max() == 255


def test_world_skips_contact_mechanics_without_contact_effects(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import sim.world as world_module

    monkeypatch.setattr(world_module, "contact_mechanics", _explode)
    world = sim.World(make_scene(effects=["membrane", "depth"]))
    for _ in range(5):
        snap = world.step()
    assert snap.pressure_pa == {"left": 0.0, "right": 0.0}


def test_still_object_reuses_the_membrane_and_stays_identical() -> None:
    scene = make_scene(effects=["membrane", "depth", "tof_noise"], duration_secs=0.2)
    simulator = sim.Simulator(scene)
    first = simulator.step()
    second = simulator.step()
    renderer = simulator.renderers["left"]
    assert renderer.membrane_cache_hits == 1
    np.testing.assert_array_equal(
        first.frames["left"].arrays["range_m"], second.frames["left"].arrays["range_m"]
    )
    # The noise is drawn per frame even when the membrane is reused.
    assert not np.array_equal(
        first.images["left"].depth_m, second.images["left"].depth_m, equal_nan=True
    )


def _without(effect: str) -> list[str]:
    """All effects but ``effect`` and those that need it."""
    return [e for e in ALL_EFFECTS if effect not in resolve([e])]


@pytest.mark.parametrize("effect", ["ir", "shear", "dot_pattern", "tof_noise"])
def test_each_camera_effect_off_is_absent_and_unpaid(
    effect: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(render_module._STEPS, effect, _explode)
    scene = make_scene(effects=_without(effect), duration_secs=0.2)
    simulator = sim.Simulator(scene)
    for _ in range(3):
        inst = simulator.step()
    arrays = inst.frames["left"].arrays
    for added in EFFECTS[effect].adds:
        if added not in ("depth_m", "amplitude") or effect == "ir":
            assert added not in arrays, added
    assert effect not in simulator.renderers["left"].calls
    if effect == "ir":
        assert inst.images["left"].ir.shape == (0, 0)
    if effect == "tof_noise":
        assert not np.isnan(inst.images["left"].depth_m).any()


def test_world_effects_off_are_absent() -> None:
    commands = [
        {"t_secs": 0.0, "command": "grasp", "width_m": 0.065, "speed_m_per_s": 0.1, "force_n": 5.0}
    ]
    simulator = sim.Simulator(
        make_scene(effects=_without("pressure"), duration_secs=0.3, gripper={"commands": commands})
    )
    for _ in range(5):
        inst = simulator.step()
    assert inst.pressures == {}
    assert inst.snapshot.speed_m_per_s == 0.0 and inst.snapshot.width_m == 0.065  # no dynamics
    simulator = sim.Simulator(make_scene(effects=_without("ground_truth"), duration_secs=0.3))
    inst = simulator.step()
    assert inst.ground_truth is None and inst.masks == {}


def test_pressure_off_computes_no_gas_law(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sim.World, "pressure_pa", _explode)
    world = sim.World(make_scene(effects=_without("pressure"), duration_secs=0.3))
    for _ in range(5):
        snap = world.step()
    assert snap.pressure_pa == {"left": 0.0, "right": 0.0}
