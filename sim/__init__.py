"""The Soft-bubble simulator: scenes, effects, membrane, ToF rendering, WSG 50 motion.

Library entry points (no runtime, no sockets):

* :func:`load_scene` reads and checks ``scenes/*.yaml``.
* :class:`Simulator` steps a scene frame by frame: ``Simulator(scene).step()`` returns
  an :class:`Instant`.
* :func:`render` renders one instant of a scene: ``render(scene, t_secs)``.
* :func:`render_grasp` renders an object at a pose and an opening, without a scene file:
  ``render_grasp("mug", tool_from_object, width_m=0.06, effects=("membrane", "depth"))``.

An :class:`Instant` holds both bubbles' ``ToFImage`` (``images["left"]``), their true
contact masks, ``Pressure`` messages (when ``pressure`` is on), the ``GripperState``, the
``GroundTruth`` (when ``ground_truth`` is on) and the ``WrenchTruth`` (when ``wrench`` is
on), all with one stamp.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from geometry.gripper import SIDES
from messages.base import Header
from messages.force import WrenchTruth
from messages.types import GripperState, GroundTruth, MaskImage, Pressure, ToFImage
from sim.effects import ALL_EFFECTS, MINIMAL_EFFECTS, resolve
from sim.scene import ObjectSpec, Scene, SceneError, load_scene, scene_from_dict

if TYPE_CHECKING:
    from sim.tof import BubbleRenderer
from sim.world import World, WorldSnapshot

__all__ = [
    "ALL_EFFECTS",
    "MINIMAL_EFFECTS",
    "BubbleRenderer",
    "Instant",
    "Scene",
    "SceneError",
    "Simulator",
    "World",
    "WorldSnapshot",
    "load_scene",
    "render",
    "render_grasp",
    "resolve",
    "scene_from_dict",
    "stamp_of",
    "wrench_truth",
]


def __getattr__(name: str) -> Any:
    """The renderer (OpenCV and the membrane model) loads on first use, so a node that
    only steps the world (gripper, pressure, world) starts without it."""
    if name in ("BubbleRenderer", "renderer"):
        from sim import tof

        return getattr(tof, name)
    raise AttributeError(f"module 'sim' has no attribute {name!r}")


def stamp_of(snap: WorldSnapshot, start_nanos: int = 0) -> int:
    """The stamp every message of this instant carries."""
    return start_nanos + int(round(snap.time_secs * 1e9))


@dataclass
class Instant:
    """Every output of the simulator at one instant (see the module docstring)."""

    snapshot: WorldSnapshot
    stamp_nanos: int
    images: dict[str, ToFImage]
    gripper: GripperState
    masks: dict[str, MaskImage] = field(default_factory=dict)
    pressures: dict[str, Pressure] = field(default_factory=dict)
    ground_truth: GroundTruth | None = None
    wrench: WrenchTruth | None = None
    frames: dict[str, Any] = field(default_factory=dict)


def gripper_state(snap: WorldSnapshot, stamp_nanos: int) -> GripperState:
    return GripperState(
        header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
        width_m=float(snap.width_m),
        speed_m_per_s=float(snap.speed_m_per_s),
        force_n=float(snap.force_n),
        state=snap.gripper_state,
    )


def pressure(snap: WorldSnapshot, side: str, stamp_nanos: int) -> Pressure:
    return Pressure(
        header=Header(stamp_nanos=stamp_nanos, frame_id=f"{side}_bubble"),
        sensor=side,
        pressure_pa=float(snap.pressure_pa[side]),
    )


def ground_truth(
    snap: WorldSnapshot, object_class: str, stamp_nanos: int, *, noise_seed: int
) -> GroundTruth:
    """Ground truth; shear is the mean membrane shift in the contact, tool (y, z), mm.

    ``noise_seed`` is the scene's seed, which draws the sensors' noise: a dataset made
    from these frames can say which noise it holds.
    """
    return GroundTruth(
        header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
        tool_from_object=np.array(snap.tool_from_object, dtype=np.float64),
        object_class=object_class,
        in_contact=bool(any(snap.in_contact.values())),
        shear_left_m=np.asarray(snap.shear_in_tool_m["left"], dtype=np.float64),
        shear_right_m=np.asarray(snap.shear_in_tool_m["right"], dtype=np.float64),
        noise_seed=int(noise_seed),
    )


def wrench_truth(snap: WorldSnapshot, stamp_nanos: int) -> WrenchTruth:
    """The world's true contact wrenches (``wrench`` effect), tool frame.

    The object feels the opposite of what it does to both bubbles (the simulated world
    has no other contact on it that pushes back: a support is kinematic).
    """
    force = np.zeros((2, 3))
    torque = np.zeros((2, 3))
    for i, side in enumerate(SIDES):
        w = snap.wrench.get(side)
        if w is not None:
            force[i], torque[i] = w.force_n, w.torque_nm
    return WrenchTruth(
        header=Header(stamp_nanos=stamp_nanos, frame_id="tool"),
        source="sim",
        bubble_force_n=force,
        bubble_torque_nm=torque,
        object_force_n=-force.sum(axis=0),
        object_torque_nm=-torque.sum(axis=0),
        pressure_pa=[float(snap.pressure_pa[s]) for s in SIDES],
        volume_m3=[float(snap.volume_m3.get(s, 0.0)) for s in SIDES],
    )


class Simulator:
    """A scene's world plus both bubbles' renderers.

    ``step()`` advances one frame; ``render_snapshot(snap)`` renders any snapshot.
    """

    def __init__(self, scene: Scene, *, start_nanos: int = 0, cached: bool = False) -> None:
        self.scene = scene
        self.world = World(scene)
        # Cached renderers are shared between simulators of the same scene (their
        # ``calls`` counters too); fresh ones cost the precomputation again.
        from sim.tof import BubbleRenderer, renderer

        make = renderer if cached else BubbleRenderer
        self.renderers = {side: make(scene, side) for side in SIDES}
        self.start_nanos = start_nanos
        self.effects = set(scene.resolved_effects)

    def step(self) -> Instant:
        return self.render_snapshot(self.world.step())

    def render_snapshot(self, snap: WorldSnapshot) -> Instant:
        stamp = stamp_of(snap, self.start_nanos)
        frames = {side: r.render(snap) for side, r in self.renderers.items()}
        instant = Instant(
            snapshot=snap,
            stamp_nanos=stamp,
            images={s: f.tof_image(self.renderers[s].camera, stamp) for s, f in frames.items()},
            gripper=gripper_state(snap, stamp),
            frames=frames,
        )
        if "pressure" in self.effects:
            instant.pressures = {s: pressure(snap, s, stamp) for s in SIDES}
        if "ground_truth" in self.effects:
            instant.ground_truth = ground_truth(
                snap, self.world.model.class_label, stamp, noise_seed=self.scene.seed
            )
            instant.masks = {s: f.contact_mask(stamp) for s, f in frames.items()}
        if "wrench" in self.effects:
            instant.wrench = wrench_truth(snap, stamp)
        return instant


def render(scene: Scene | str, t_secs: float, *, start_nanos: int = 0) -> Instant:
    """Render a scene at ``t_secs`` (the world is stepped from 0 to that frame)."""
    if isinstance(scene, str):
        scene = load_scene(scene)
    sim = Simulator(scene, start_nanos=start_nanos, cached=True)
    return sim.render_snapshot(sim.world.run_to(t_secs))


def render_grasp(
    obj: str,
    tool_from_object: np.ndarray,
    width_m: float,
    *,
    effects: tuple[str, ...] | list[str] = MINIMAL_EFFECTS,
    seed: int = 0,
    dims_m: dict[str, float] | None = None,
    anchor_tool_from_object: np.ndarray | None = None,
    frame_index: int = 0,
    scene: Scene | None = None,
) -> Instant:
    """Render both bubbles for an object held at a pose and an opening.

    Args:
        obj: a ``geometry.objects`` name (``mug``, ``pet_bottle``, ...).
        tool_from_object: 4x4 pose of the object frame G in the tool frame.
        width_m: the jaw opening.
        effects: which effects to compute (closed over their needs).
        seed: noise seed (with ``frame_index``, it fixes the noise bit for bit).
        dims_m: dimension overrides for the object.
        anchor_tool_from_object: the object's pose when contact began; the shear is the
            motion from it to ``tool_from_object`` (None: no shear).
        frame_index: selects the noise draw.
        scene: a scene to take the bubble, camera, pattern and noise settings from
            (its object, effects and seed are replaced).

    Returns:
        An :class:`Instant` stamped at 0 (time = frame_index / frame rate).
    """
    spec = ObjectSpec(name=obj, dims_m=tuple(sorted((dims_m or {}).items())))
    base = scene if scene is not None else Scene(name="render_grasp", object=spec)
    import dataclasses

    scene = dataclasses.replace(base, object=spec, effects=tuple(effects), seed=seed)
    world = World(scene)
    pose = np.asarray(tool_from_object, dtype=np.float64)
    in_contact: dict[str, bool] = {}
    pressures: dict[str, float] = {}
    shear: dict[str, np.ndarray] = {}
    anchors: dict[str, np.ndarray | None] = {}
    for side in SIDES:
        state = world.contact(side, width_m, pose, anchor=anchor_tool_from_object)
        in_contact[side] = state.in_contact
        pressures[side] = world.pressure_pa(state)
        shear[side] = state.shear_in_tool_m
        anchors[side] = anchor_tool_from_object if state.in_contact else None
    snap = WorldSnapshot(
        frame_index=frame_index,
        time_secs=frame_index * scene.frame_period_secs,
        tool_from_object=pose,
        width_m=float(width_m),
        force_n=world.grip_force_n(width_m, pose),
        gripper_state="holding" if any(in_contact.values()) else "idle",
        in_contact=in_contact,
        pressure_pa=pressures,
        anchors=anchors,
        shear_in_tool_m=shear,
    )
    return Simulator(scene, cached=True).render_snapshot(snap)
