"""Between ``sim.world.WorldSnapshot`` and the ``messages.sim.WorldState`` on the wire.

Kept in ``sim/`` (not in the nodes) so the world node and every sensor node convert the
same way, and so tests can round-trip without a runtime. The sensor nodes' shared
parameter class lives here too, since no node imports another.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Literal

import msgspec
import numpy as np

from geometry.gripper import SIDES
from messages.base import Header
from messages.sim import WorldState
from messages.types import GripperCommand
from sim.scene import ObjectSpec, Scene, load_scene
from sim.world import World, WorldSnapshot


class SensorParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of a per-bubble sensor node: ``sensor`` is ``left`` or ``right``."""

    sensor: Literal["left", "right"]


def to_message(snap: WorldSnapshot, scene: Scene, stamp_nanos: int) -> WorldState:
    """The wire form of a snapshot of ``scene``."""
    anchors = [snap.anchors[s] for s in SIDES]
    return WorldState(
        header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
        scene_path=scene.path,
        effects=list(scene.effects),
        seed=int(scene.seed),
        frame_index=snap.frame_index,
        time_secs=float(snap.time_secs),
        tool_from_object=np.asarray(snap.tool_from_object, dtype=np.float64),
        width_m=float(snap.width_m),
        speed_m_per_s=float(snap.speed_m_per_s),
        force_n=float(snap.force_n),
        gripper_state=snap.gripper_state,
        in_contact=[bool(snap.in_contact[s]) for s in SIDES],
        pressure_pa=[float(snap.pressure_pa[s]) for s in SIDES],
        has_anchor=[a is not None for a in anchors],
        anchor_left=np.eye(4) if anchors[0] is None else np.asarray(anchors[0], np.float64),
        anchor_right=np.eye(4) if anchors[1] is None else np.asarray(anchors[1], np.float64),
        shear_left_m=np.asarray(snap.shear_in_tool_m["left"], np.float64),
        shear_right_m=np.asarray(snap.shear_in_tool_m["right"], np.float64),
        **_membranes(snap),
        object_dims_m=dict(scene.object.dims_m),
        object_variant=-1 if scene.object.variant is None else int(scene.object.variant),
        tension_n_per_m=float(scene.bubble.tension_n_per_m),
    )


def _membranes(snap: WorldSnapshot) -> dict[str, object]:
    if snap.membranes_f is None:
        return {}
    return {
        "membrane_spacing_m": float(snap.membrane_spacing_m),
        "membrane_left_m": np.asarray(snap.membranes_f["left"], np.float32),
        "membrane_right_m": np.asarray(snap.membranes_f["right"], np.float32),
    }


def from_message(msg: WorldState) -> WorldSnapshot:
    """The snapshot a ``WorldState`` carries."""
    anchors = {"left": msg.anchor_left, "right": msg.anchor_right}
    return WorldSnapshot(
        frame_index=msg.frame_index,
        time_secs=msg.time_secs,
        tool_from_object=np.asarray(msg.tool_from_object),
        width_m=msg.width_m,
        speed_m_per_s=msg.speed_m_per_s,
        force_n=msg.force_n,
        gripper_state=msg.gripper_state,
        in_contact=dict(zip(SIDES, msg.in_contact, strict=True)),
        pressure_pa=dict(zip(SIDES, msg.pressure_pa, strict=True)),
        anchors={
            s: (np.asarray(anchors[s]) if has else None)
            for s, has in zip(SIDES, msg.has_anchor, strict=True)
        },
        shear_in_tool_m={
            "left": np.asarray(msg.shear_left_m),
            "right": np.asarray(msg.shear_right_m),
        },
        membranes_f=(
            {"left": np.asarray(msg.membrane_left_m), "right": np.asarray(msg.membrane_right_m)}
            if msg.membrane_spacing_m > 0
            else None
        ),
        membrane_spacing_m=msg.membrane_spacing_m,
    )


def scene_of(msg: WorldState) -> Scene:
    """The scene a ``WorldState`` was produced from, holding the message's object (a
    variant the world placed in the file's scene) and membrane tension (loaded once per
    path, effects, seed, object and tension)."""
    scene = _scene(
        msg.scene_path,
        tuple(msg.effects),
        msg.seed,
        tuple(sorted(msg.object_dims_m.items())),
        msg.object_variant,
    )
    if msg.tension_n_per_m > 0 and msg.tension_n_per_m != scene.bubble.tension_n_per_m:
        bubble = dataclasses.replace(scene.bubble, tension_n_per_m=msg.tension_n_per_m)
        scene = dataclasses.replace(scene, bubble=bubble)
    return scene


@functools.lru_cache(maxsize=8)
def _scene(
    path: str,
    effects: tuple[str, ...],
    seed: int,
    dims_m: tuple[tuple[str, float], ...],
    variant: int,
) -> Scene:
    scene = load_scene(path)
    if not dims_m and variant < 0:
        return dataclasses.replace(scene, effects=effects, seed=seed)  # the file's object
    held = ObjectSpec(
        name=scene.object.name, dims_m=dims_m, variant=None if variant < 0 else variant
    )
    return dataclasses.replace(scene, effects=effects, seed=seed, object=held)


def apply_command(world: World, msg: GripperCommand) -> str | None:
    """Apply a gripper command to the world; return why it was refused, or None."""
    try:
        world.command(
            msg.command,
            width_m=msg.width_m,
            speed_m_per_s=msg.speed_m_per_s,
            force_n=msg.force_n,
        )
    except ValueError as err:
        return str(err)
    return None
