"""Auto-labelling (paper, tactile classification): random grasps, and a world that takes them.

``supervisor.autolabel`` commands the run, grasp after grasp:

    place (random object and pose, after a random drop) -> settle -> close -> wait for a
    stable grasp -> hold ``hold_secs`` (the dataset writer keeps those frames) -> release

Ports:
    inputs: ``grasp`` (GraspState) from the grasp monitor, which also paces the run
        (its stamps are the world's clock); ``progress`` (TaskEvent, optional) from the
        dataset writer, counted for the progress line.
    outputs: ``place`` (messages.classify.GraspRequest) to the world, ``command``
        (GripperCommand) to the gripper, ``event`` (TaskEvent, task ``autolabel``):
        ``run_start`` (data: a ``RunStart``, the seeds and scene parameters),
        ``grasp_start`` (a ``GraspStart``, the grasp's parameters), ``grasp_end``,
        ``grasp_failed`` (a ``GraspRef``; failed: no stable grasp in
        ``stable_timeout_secs``), ``run_end`` (a ``RunEnd``); records of
        ``messages.tasks``.

Grasp ``i`` is ``perception.classify.autolabel.GraspGenerator(seed).sample(i)``, so a
run is deterministic per seed; with ``resume`` the grasps the dataset's manifest already
holds are skipped. A line per grasp shows progress (done, frames, rate, time left).

``world.autolabel`` is the simulated world of this graph: ``world.sim``'s world
(``sim.World``) whose object and pose are set by each ``GraspRequest`` (the scene file
of that object gives the bubbles, cameras and noise; the request's variant, if any, the
object's dimensions) instead of a scripted trajectory.

Ports:
    inputs: ``place`` (GraspRequest), ``command`` (GripperCommand).
    outputs: ``state`` (messages.sim.WorldState) per camera frame, which the standard
        ``bubble_camera.sim``, ``pressure.sim`` and ``gripper.sim`` nodes render;
        ``ground_truth`` (GroundTruth): the object's class, the labels' source.

A hardware graph drops ``world.autolabel`` and routes ``place`` to the arm.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from messages.base import Header
from messages.classify import GraspRequest
from messages.sim import WorldState
from messages.tasks import (
    GraspRef,
    GraspSkipped,
    GraspStart,
    GraspWritten,
    RunEnd,
    RunStart,
    TaskData,
    TaskEventName,
)
from messages.types import GraspState, GripperAction, GripperCommand, GroundTruth, TaskEvent
from perception.classify.autolabel import (
    DEFAULT_OBJECTS,
    GraspGenerator,
    GraspGeneratorParams,
    GraspSample,
)
from perception.classify.dataset import DatasetError, read_manifest
from runtime.node import Node
from runtime.params import build_params
from runtime.registry import register
from sim import World, ground_truth, load_scene, stamp_of
from sim.effects import resolve
from sim.scene import Keyframe, ObjectSpec, Scene, SceneError, rpy_deg_from_rotation
from sim.wire import apply_command, to_message

TASK = "autolabel"


class AutolabelParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of the auto-labelling supervisor."""

    seed: Annotated[
        int, Meta(description="the run's seed (grasp ``i`` depends only on ``(seed, i)``).")
    ] = 0
    grasps: Annotated[
        int, Meta(ge=1, description="how many grasps the run makes (ids ``0 .. grasps - 1``).")
    ] = 200
    dataset: Annotated[
        str,
        Meta(
            description=(
                "the dataset directory the writer fills; with ``resume`` its manifest "
                "says which grasps are done."
            )
        ),
    ] = "out/datasets/autolabel"
    resume: Annotated[bool, Meta(description="skip grasps already in the dataset.")] = True
    objects: Annotated[tuple[str, ...], Meta(description="object names to grasp.")] = (
        DEFAULT_OBJECTS
    )
    variants: Annotated[
        str,
        Meta(
            description=(
                "``none`` (each class's reference shape), ``train`` or ``held_out`` (a "
                "variant of its class from that split, ``geometry.variants``: a test set "
                "asks for ``held_out``, a training set for ``train``)."
            )
        ),
    ] = "none"
    open_width_m: Annotated[
        float, Meta(gt=0, le=0.11, description="opening before each grasp and after each release.")
    ] = 0.11
    close_speed_m_per_s: Annotated[float, Meta(gt=0, description="finger speed of the grasp.")] = (
        0.1
    )
    settle_secs: Annotated[
        float, Meta(ge=0, description="wait after placing an object before closing.")
    ] = 0.2
    stable_timeout_secs: Annotated[
        float, Meta(gt=0, description="give up on a grasp not stable this long after closing.")
    ] = 3.0
    hold_secs: Annotated[
        float,
        Meta(gt=0, description="how long a stable grasp is held (frames recorded meanwhile)."),
    ] = 1.0
    release_secs: Annotated[
        float, Meta(ge=0, description="wait after opening, before the next drop.")
    ] = 0.3
    approach_tilt_deg: Annotated[
        float, Meta(description="ranges of the random pose (``GraspGeneratorParams``).")
    ] = 40.0
    skew_deg: Annotated[
        float, Meta(description="ranges of the random pose (``GraspGeneratorParams``).")
    ] = 8.0
    offset_m: Annotated[
        float, Meta(description="ranges of the random pose (``GraspGeneratorParams``).")
    ] = 0.006
    end_fraction: Annotated[
        float,
        Meta(
            description=(
                "more grasps near the objects' ends, for training "
                "(``GraspGeneratorParams``; 0, the default, for a held-out set)."
            )
        ),
    ] = 0.0
    end_band_m: Annotated[
        float,
        Meta(
            description=(
                "more grasps near the objects' ends, for training "
                "(``GraspGeneratorParams``; 0, the default, for a held-out set)."
            )
        ),
    ] = 0.02
    start_delay_secs: Annotated[
        float, Meta(ge=0, description="wall time before the first grasp (lets the graph settle).")
    ] = 0.5
    end_grace_secs: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "at the end, how long to wait for the writer to confirm the last grasps"
                " (its frames may trail under load) before stopping the graph."
            ),
        ),
    ] = 30.0

    def __post_init__(self) -> None:
        if not self.dataset:
            raise ValueError("`dataset` must be a directory path, got ''")
        self.generator_params()  # checks the object names and ranges

    def generator_params(self) -> GraspGeneratorParams:
        """The generator's parameters, checked against its declaration."""
        given = {"objects": tuple(self.objects), "variants": self.variants, "seed": self.seed}
        for name in ("approach_tilt_deg", "skew_deg", "offset_m", "end_fraction", "end_band_m"):
            given[name] = getattr(self, name)
        params: GraspGeneratorParams = build_params(GraspGeneratorParams, given)
        return params


@register("supervisor.autolabel")
class AutolabelSupervisor(Node):
    """Random grasps, one after the other (see the module docstring)."""

    Params = AutolabelParams
    inputs = {"grasp": GraspState, "progress": TaskEvent}
    optional_inputs = frozenset({"progress"})
    outputs = {"place": GraspRequest, "command": GripperCommand, "event": TaskEvent}

    def setup(self) -> None:
        self.generator = GraspGenerator(self.params.generator_params())
        done: set[int] = set()
        if self.params.resume and Path(self.params.dataset, "manifest.json").exists():
            try:
                manifest = read_manifest(self.params.dataset)
            except DatasetError as err:
                raise ValueError(f"{self.name}: params.dataset: {err}") from err
            done = {int(g["grasp_id"]) for g in manifest["grasps"]}
        self.todo = [i for i in range(self.params.grasps) if i not in done]
        self.skipped = self.params.grasps - len(self.todo)
        self.phase = "idle"
        self.current: GraspSample | None = None
        self.phase_start_nanos: int | None = None
        self.finished = 0
        self.failed = 0
        self.frames_written = 0
        self.writer_acked: set[int] = set()
        self.writer_skipped = 0
        self.ended: set[int] = set()
        self.wall_start = time.monotonic()
        self.end_wait_start: float | None = None
        self.io.add_timer(self.params.start_delay_secs or 0.01, self._tick)

    # -- the run ----------------------------------------------------------------------

    def _event(self, event: TaskEventName, data: TaskData, stamp: int = 0) -> None:
        self.io.publish(
            "event",
            TaskEvent(header=Header(stamp_nanos=stamp), task=TASK, event=event, data=data),
        )

    def _tick(self) -> None:
        """Wall-clock timer: starts the run, and ends it once the writer caught up."""
        if self.phase == "idle":
            gen = self.generator.params
            self._event(
                "run_start",
                RunStart(
                    seeds={"autolabel": self.params.seed},
                    scene={
                        "generator": {
                            k: (list(v) if isinstance(v, tuple) else v)
                            for k, v in msgspec.structs.asdict(gen).items()
                        },
                        "open_width_m": self.params.open_width_m,
                        "close_speed_m_per_s": self.params.close_speed_m_per_s,
                        "hold_secs": self.params.hold_secs,
                    },
                ),
            )
            self.io.log.info(
                "%s: %d grasps to make (%d already in %s)",
                self.name,
                len(self.todo),
                self.skipped,
                self.params.dataset,
            )
            self._next_grasp(0)
        elif self.phase == "done":
            waited = time.monotonic() - (self.end_wait_start or time.monotonic())
            pending = {g for g in self.ended if g not in self.writer_acked}
            if not pending or waited > self.params.end_grace_secs:
                self.phase = "stopped"
                if pending:
                    self.io.log.warning(
                        "%s: the writer confirmed no grasp of %d held (%s) within "
                        "end_grace_secs; their frames may be lost",
                        self.name,
                        len(pending),
                        sorted(pending)[:20],
                    )
                self.io.request_stop(
                    f"autolabel: {self.finished} grasps held, {self.failed} failed, "
                    f"{self.writer_skipped} skipped by the writer (no stable frame), "
                    f"{len(pending)} not confirmed; "
                    f"{self.frames_written} frames written to {self.params.dataset}"
                )

    def _next_grasp(self, stamp: int) -> None:
        if not self.todo:
            self._event("run_end", RunEnd(finished=self.finished, failed=self.failed), stamp)
            self.phase = "done"
            self.end_wait_start = time.monotonic()
            return
        grasp_id = self.todo.pop(0)
        sample = self.generator.sample(grasp_id)
        self.current = sample
        self._event("grasp_start", GraspStart(grasp_id=grasp_id, params=sample.to_params()), stamp)
        self.io.publish(
            "place",
            GraspRequest(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                grasp_id=grasp_id,
                object_name=sample.object_name,
                class_label=sample.class_label,
                tool_from_object=sample.tool_from_object,
                open_width_m=self.params.open_width_m,
                grasp_width_m=sample.grasp_width_m,
                force_n=sample.force_n,
                variant=-1 if sample.variant is None else sample.variant,
            ),
        )
        self.phase = "settle"
        self.phase_start_nanos = None

    def on_grasp(self, msg: GraspState) -> None:
        """The grasp monitor's state paces the run (its stamps are the world's clock)."""
        if self.phase in ("idle", "done", "stopped") or self.current is None:
            return
        now = msg.header.stamp_nanos
        if self.phase_start_nanos is None:
            self.phase_start_nanos = now
        elapsed = (now - self.phase_start_nanos) * 1e-9
        p = self.params
        if self.phase == "settle" and elapsed >= p.settle_secs and not msg.stable:
            self._command("grasp", self.current.grasp_width_m, self.current.force_n, now)
            self._enter("closing", now)
        elif self.phase == "closing":
            if msg.stable:
                self._enter("holding", now)
            elif elapsed > p.stable_timeout_secs:
                self.failed += 1
                self._event("grasp_failed", GraspRef(grasp_id=self.current.grasp_id), now)
                self._release(now)
        elif self.phase == "holding" and (elapsed >= p.hold_secs or not msg.stable):
            self.ended.add(self.current.grasp_id)
            self._event("grasp_end", GraspRef(grasp_id=self.current.grasp_id), now)
            self.finished += 1
            self._progress()
            self._release(now)
        elif self.phase == "releasing" and elapsed >= p.release_secs and not msg.stable:
            self._next_grasp(now)  # the object drops; the next grasp finds it elsewhere

    def on_progress(self, msg: TaskEvent) -> None:
        data = msg.data
        if isinstance(data, GraspWritten):
            self.writer_acked.add(data.grasp_id)
            self.frames_written += data.frames
        elif isinstance(data, GraspSkipped):
            self.writer_acked.add(data.grasp_id)
            self.writer_skipped += 1

    def _enter(self, phase: str, now: int) -> None:
        self.phase = phase
        self.phase_start_nanos = now

    def _release(self, now: int) -> None:
        self._command("release", self.params.open_width_m, 0.0, now)
        self._enter("releasing", now)

    def _command(self, command: GripperAction, width_m: float, force_n: float, stamp: int) -> None:
        self.io.publish(
            "command",
            GripperCommand(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                command=command,
                width_m=float(width_m),
                speed_m_per_s=self.params.close_speed_m_per_s,
                force_n=float(force_n),
            ),
        )

    def _progress(self) -> None:
        done = self.finished + self.failed
        total = done + len(self.todo)
        rate = (time.monotonic() - self.wall_start) / max(done, 1)
        self.io.log.info(
            "%s: grasp %d/%d (%s) held; %d failed, %d frames written, %.1f s/grasp, ~%.0f s left",
            self.name,
            done,
            total,
            self.current.object_name if self.current else "?",
            self.failed,
            self.frames_written,
            rate,
            rate * len(self.todo),
        )


DEFAULT_SCENES = {
    "mug": "scenes/mug_grasp.yaml",
    "pet_bottle": "scenes/pet_bottle.yaml",
    "square_bottle": "scenes/square_bottle.yaml",
    "wine_glass": "scenes/wine_glass.yaml",
}
DEFAULT_EFFECTS = ("membrane", "depth", "ir", "tof_noise", "pressure", "gripper", "ground_truth")


class AutolabelWorldParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``scenes``: object name -> scene file (bubbles, cameras, noise; its object must be
    that one); ``effects`` and ``seed`` replace the scenes'; ``rate_scale`` > 1 runs
    faster than real time."""

    scenes: dict[str, str] = msgspec.field(default_factory=lambda: dict(DEFAULT_SCENES))
    effects: tuple[str, ...] = DEFAULT_EFFECTS
    seed: int = 0
    rate_scale: Annotated[float, Meta(gt=0)] = 1.0

    def __post_init__(self) -> None:
        try:
            resolve(self.effects)
        except ValueError as err:
            raise ValueError(f"`effects`: {err}") from err
        if "ground_truth" not in self.effects:
            raise ValueError("`effects` must include 'ground_truth' (the labels come from it)")
        for name, path in self.scenes.items():
            try:
                scene = load_scene(path)
            except SceneError as err:
                raise ValueError(f"`scenes`: {err}") from err
            if scene.object.name != name:
                raise ValueError(
                    f"`scenes`: {path} holds a {scene.object.name!r}, listed for {name!r}"
                )

    def scene_for(self, request: GraspRequest) -> Scene:
        """The object's scene, holding it still at the requested pose, jaws open."""
        if request.object_name not in self.scenes:
            raise ValueError(f"no scene for object {request.object_name!r}: {sorted(self.scenes)}")
        base = load_scene(self.scenes[request.object_name])
        if request.variant >= 0:
            base = dataclasses.replace(
                base, object=ObjectSpec.of(request.object_name, request.variant)
            )
        pose = np.asarray(request.tool_from_object, dtype=np.float64)
        keyframe = Keyframe(
            t_secs=0.0,
            xyz_m=(float(pose[0, 3]), float(pose[1, 3]), float(pose[2, 3])),
            rpy_deg=rpy_deg_from_rotation(pose[:3, :3]),
        )
        gripper = dataclasses.replace(
            base.gripper, initial_width_m=float(request.open_width_m), commands=()
        )
        scene = dataclasses.replace(
            base,
            effects=tuple(self.effects),
            seed=self.seed,
            trajectory=(keyframe,),
            mount_rpy_deg=(0.0, 0.0, 0.0),
            gripper=gripper,
            duration_secs=1e6,  # the supervisor decides when a grasp ends
        )
        if not np.allclose(scene.tool_from_object(0.0), pose, atol=1e-9):
            raise ValueError("pose does not survive the roll-pitch-yaw round trip")
        return scene


@register("world.autolabel")
class AutolabelWorld(Node):
    """The simulated world, with objects placed by ``GraspRequest`` (module docstring)."""

    Params = AutolabelWorldParams
    clocked = True  # one step per frame period, whatever it hears
    inputs = {"place": GraspRequest, "command": GripperCommand}
    optional_inputs = frozenset({"command"})
    outputs = {"state": WorldState, "ground_truth": GroundTruth}

    def setup(self) -> None:
        self.world: World | None = None
        self.frames = 0
        self.start_nanos: int | None = None
        self.period_secs = (
            1.0 / load_scene(next(iter(self.params.scenes.values()))).camera.frame_rate_hz
        )
        self.io.add_timer(self.period_secs / self.params.rate_scale, self.tick)

    def on_place(self, msg: GraspRequest) -> None:
        try:
            scene = self.params.scene_for(msg)
        except ValueError as err:
            self.io.log.error("%s: cannot place grasp %d: %s", self.name, msg.grasp_id, err)
            return
        self.world = World(scene)

    def on_command(self, msg: GripperCommand) -> None:
        if self.world is None:
            return
        refused = apply_command(self.world, msg)
        if refused:
            self.io.log.warning("%s: ignored gripper command: %s", self.name, refused)

    def tick(self) -> None:
        """Advance the placed object's world one frame; nothing until the first place."""
        if self.world is None:
            return
        if self.start_nanos is None:
            self.start_nanos = self.io.now_nanos()
        snap = self.world.step()
        # One clock over all grasps (each grasp's world starts at 0): stamps and the
        # frame index (which draws the sensor noise) keep counting.
        snap = dataclasses.replace(
            snap, frame_index=self.frames, time_secs=self.frames * self.period_secs
        )
        self.frames += 1
        stamp = stamp_of(snap, self.start_nanos)
        self.io.publish("state", to_message(snap, self.world.scene, stamp))
        truth = ground_truth(
            snap, self.world.model.class_label, stamp, noise_seed=self.world.scene.seed
        )
        self.io.publish("ground_truth", truth)
