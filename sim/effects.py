"""The simulator's effects: units that declare what they need and what they add.

A scene lists its effects; :func:`resolve` closes the list over ``needs`` and returns it
in the one order they run in. The simulator computes those and nothing else
(docs/design.md, principle 3). Camera effects run per bubble in ``sim.tof``; world effects
run once per instant in ``sim.world``.

=============  ======  ======================  =====================================
effect         stage   needs                   adds
=============  ======  ======================  =====================================
membrane       camera  -                       range_m, indentation_m, contact
depth          camera  membrane                depth_m
ir             camera  membrane                amplitude (IR, before quantization)
shear          camera  membrane                material_shift_m (tangential, F y/z)
dot_pattern    camera  ir                      albedo (amplitude multiplied by it)
tof_noise      camera  depth, ir               depth_m and amplitude with noise, NaNs
pressure       world   -                       pressure_pa per bubble (gas law)
gripper        world   pressure                speed-limited, force-controlled jaws
ground_truth   world   -                       GroundTruth (pose, contact, shear)
wrench         world   pressure                each bubble's true contact wrench
slip           world   wrench                  the object slides under its load
=============  ======  ======================  =====================================

``wrench`` (``sim.friction``) also bounds each point's stick shift by its friction limit
(``friction * p / stiffness``, smaller at the patch's edge) where ``shear`` renders the
material's shift, so the dots show partial slip as the true wrench does. ``slip`` moves
the object in the hand under the scene's ``load`` (weight, filling, a pull) against the
bubbles' friction, so a firmer grasp holds what a light one drops.

``dot_pattern`` uses ``material_shift_m`` when ``shear`` is also listed (the dots move
with the membrane); without ``shear`` the dots stay where the rest membrane holds them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class Effect:
    """One effect: its stage, what it needs, what it adds to the frame it runs on."""

    name: str
    stage: str
    needs: tuple[str, ...]
    adds: tuple[str, ...]
    doc: str


# Listed in the order they run: every effect comes after what it needs.
EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "membrane",
            "camera",
            (),
            ("range_m", "indentation_m", "contact"),
            "bubble surface deformed around the object",
        ),
        Effect("depth", "camera", ("membrane",), ("depth_m",), "ToF z-depth image"),
        Effect("ir", "camera", ("membrane",), ("amplitude",), "IR amplitude image"),
        Effect(
            "shear",
            "camera",
            ("membrane",),
            ("material_shift_m",),
            "tangential membrane displacement",
        ),
        Effect("dot_pattern", "camera", ("ir",), ("albedo",), "printed dots seen in IR"),
        Effect(
            "tof_noise",
            "camera",
            ("depth", "ir"),
            ("depth_m", "amplitude", "invalid"),
            "range noise and invalid pixels",
        ),
        Effect("pressure", "world", (), ("pressure_pa",), "ideal-gas bubble pressure"),
        Effect(
            "gripper",
            "world",
            ("pressure",),
            ("width_m", "speed_m_per_s", "force_n"),
            "speed-limited, force-controlled fingers",
        ),
        Effect("ground_truth", "world", (), ("ground_truth",), "true pose, contact, shear"),
        Effect("wrench", "world", ("pressure",), ("wrench",), "true contact wrench per bubble"),
        Effect("slip", "world", ("wrench",), ("slide_m",), "the object slides under its load"),
    )
}

ALL_EFFECTS: tuple[str, ...] = tuple(EFFECTS)
MINIMAL_EFFECTS: tuple[str, ...] = ("membrane", "depth")


def resolve(listed: Iterable[str]) -> tuple[str, ...]:
    """Close ``listed`` over ``needs``; return the effects to compute, in run order.

    Raises:
        ValueError: an unknown effect name (the message lists the valid ones).
    """
    wanted: set[str] = set()
    stack = list(listed)
    while stack:
        name = stack.pop()
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; valid: {', '.join(ALL_EFFECTS)}")
        if name not in wanted:
            wanted.add(name)
            stack.extend(EFFECTS[name].needs)
    return tuple(n for n in ALL_EFFECTS if n in wanted)


def camera_effects(resolved: Iterable[str]) -> tuple[str, ...]:
    """The camera-stage effects of a resolved list, in run order."""
    names = set(resolved)
    return tuple(n for n in ALL_EFFECTS if n in names and EFFECTS[n].stage == "camera")
