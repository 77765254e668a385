"""Scene files: what the simulator shows, loaded from YAML and checked.

A scene names the object (one of ``geometry.objects``, optionally one of its class's
variants, ``geometry.variants``, and dimension overrides), its pose trajectory in the tool frame, the scripted gripper commands, the
bubbles, the cameras, the dot pattern, the noise, the seed and the ``effects`` to
simulate, optionally a ``support`` the arm lowers the held object onto
(``sim.support``), and the ``load`` on the held object (``sim.friction``: its mass, a
filling, a pull; used by the ``slip`` effect). The hardware's sections (gripper, bubble, camera, pattern, noise,
membrane) are defined in ``sim.rig``. Every section but ``object`` is optional and
defaults to docs/facts.md figures::

    name: mug_grasp
    seed: 7
    duration_secs: 4.0
    effects: [membrane, depth, ir, dot_pattern, shear, tof_noise, pressure, gripper, ground_truth]
    object: {name: mug, dims_m: {radius_m: 0.04}}   # or {name: mug, variant: 1003}
    mount_rpy_deg: [0, -90, -90]     # object axis along tool y, mug handle along tool z
    trajectory:                      # keyframes of the held frame in the tool frame
      - {t_secs: 0.0, xyz_m: [0, 0, 0.005], rpy_deg: [0, 0, 0]}
    gripper:
      initial_width_m: 0.11
      commands:
        - {t_secs: 0.2, command: grasp, width_m: 0.07, force_n: 12}

Rotations in keyframes are roll-pitch-yaw in degrees, ``R = Rz(yaw) Ry(pitch) Rx(roll)``
(extrinsic x, then y, then z). Poses interpolate linearly in translation and along the
geodesic in rotation. Errors name the file and the field.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import yaml

from geometry.gripper import GripperGeometry
from geometry.se3 import exp_so3, log_so3
from messages.files import load_yaml, read_text
from sim.effects import ALL_EFFECTS, resolve
from sim.friction import LoadSpec
from sim.rig import (
    BubbleSpec,
    CameraSpec,
    GripperSpec,
    MembraneSpec,
    NoiseSpec,
    PatternSpec,
    ScriptedCommand,
    nonnegative,
    positive,
)
from sim.support import SupportSpec


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True, kw_only=True)
class ObjectSpec:
    """Which object, and dimension overrides passed to ``geometry.objects.make``.

    ``variant``: the class's variant (``geometry.variants``) the dimensions came from, or
    None; ``dims_m`` holds the variant's dimensions already (:meth:`of` resolves them).
    """

    name: str
    dims_m: tuple[tuple[str, float], ...] = ()
    variant: int | None = None

    @classmethod
    def of(
        cls, name: str, variant: int | None = None, dims_m: dict[str, float] | None = None
    ) -> ObjectSpec:
        """An object, the dimensions of ``variant`` (if given) overridden by ``dims_m``.

        Raises:
            ValueError: an unknown class or a variant id in no split.
        """
        dims: dict[str, float] = {}
        if variant is not None:
            from geometry.variants import variant_dims

            dims = variant_dims(name, int(variant))
        dims.update(dims_m or {})
        return cls(name=name, dims_m=tuple(sorted(dims.items())), variant=variant)

    def model(self) -> Any:
        """The shared object model (cached)."""
        return _object_model(self.name, self.dims_m)


@functools.cache
def _object_model(name: str, dims: tuple[tuple[str, float], ...]) -> Any:
    from geometry import objects

    return objects.make(name, **dict(dims))


@dataclass(frozen=True, kw_only=True)
class Keyframe:
    """``tool_from_object`` at one time: translation (m) and roll-pitch-yaw (deg)."""

    t_secs: float
    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        nonnegative(self, "t_secs")
        for name in ("xyz_m", "rpy_deg"):
            if not all(math.isfinite(v) for v in getattr(self, name)):
                raise ValueError(f"`{name}` must be finite, got {getattr(self, name)!r}")

    def pose(self) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, :3] = rotation_from_rpy_deg(self.rpy_deg)
        pose[:3, 3] = self.xyz_m
        return pose


def rotation_from_rpy_deg(rpy_deg: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` from degrees."""
    r, p, y = np.radians(np.asarray(rpy_deg, dtype=np.float64))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rpy_deg_from_rotation(rot: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (degrees) with ``rot = Rz(yaw) Ry(pitch) Rx(roll)`` (sim scenes)."""
    pitch = math.asin(max(-1.0, min(1.0, -rot[2, 0])))
    if math.cos(pitch) > 1e-9:
        roll = math.atan2(rot[2, 1], rot[2, 2])
        yaw = math.atan2(rot[1, 0], rot[0, 0])
    else:  # gimbal lock: only roll -+ yaw is defined; put it all in yaw
        roll = 0.0
        yaw = math.atan2(-rot[0, 1], rot[1, 1])
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


@dataclass(frozen=True, kw_only=True)
class Scene:
    """A whole scene (see the module docstring). Hashable: renderers cache on it."""

    name: str
    object: ObjectSpec
    seed: int = 0
    duration_secs: float = 1.0
    effects: tuple[str, ...] = ALL_EFFECTS
    trajectory: tuple[Keyframe, ...] = (Keyframe(t_secs=0.0),)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gripper: GripperSpec = field(default_factory=GripperSpec)
    bubble: BubbleSpec = field(default_factory=BubbleSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    pattern: PatternSpec = field(default_factory=PatternSpec)
    noise: NoiseSpec = field(default_factory=NoiseSpec)
    membrane: MembraneSpec = field(default_factory=MembraneSpec)
    support: SupportSpec | None = None  # a surface the arm lowers the object onto
    load: LoadSpec = field(default_factory=LoadSpec)  # weight and pull (the ``slip`` effect)
    path: str = ""

    def __post_init__(self) -> None:
        positive(self, "duration_secs")
        resolve(self.effects)
        if not self.trajectory:
            raise ValueError("`trajectory` must hold at least one keyframe")
        times = [k.t_secs for k in self.trajectory]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"`trajectory` times must increase, got {times}")

    @property
    def resolved_effects(self) -> tuple[str, ...]:
        """The listed effects closed over their needs, in run order."""
        return resolve(self.effects)

    @property
    def frame_period_secs(self) -> float:
        return 1.0 / self.camera.frame_rate_hz

    @property
    def frame_count(self) -> int:
        """Frames in the scene: t = 0, dt, ..., duration."""
        return int(math.floor(self.duration_secs * self.camera.frame_rate_hz + 1e-9)) + 1

    def gripper_geometry(self) -> GripperGeometry:
        return _gripper_geometry(self.bubble, self.camera, self.gripper)

    def object_model(self) -> Any:
        return self.object.model()

    def tool_from_object(self, t_secs: float) -> np.ndarray:
        """The scripted object pose at ``t_secs`` (held constant outside the keyframes).

        Keyframes move a held frame H; ``tool_from_object = tool_from_H @ Rot(mount)``,
        so perturbation angles in keyframes are about tool axes whatever the mount.
        """
        pose = _interpolate(self.trajectory, t_secs)
        pose[:3, :3] = pose[:3, :3] @ _mount(self.mount_rpy_deg)
        return pose

    def with_effects(self, effects: tuple[str, ...] | list[str]) -> Scene:
        """The same scene with another effect list."""
        return _replace(self, effects=tuple(effects))


@functools.cache
def _gripper_geometry(
    bubble: BubbleSpec, camera: CameraSpec, gripper: GripperSpec
) -> GripperGeometry:
    return GripperGeometry(
        bubble=bubble.geometry(),
        plate_outset_m=gripper.plate_outset_m,
        camera_back_m=camera.back_m,
        camera_z_m=camera.z_m,
        camera_pitch_deg=camera.pitch_deg,
        max_width_m=gripper.max_width_m,
    )


@functools.cache
def _mount(rpy_deg: tuple[float, float, float]) -> np.ndarray:
    return rotation_from_rpy_deg(rpy_deg)


def _replace(scene: Scene, **changes: Any) -> Scene:
    import dataclasses

    return dataclasses.replace(scene, **changes)


def _interpolate(frames: tuple[Keyframe, ...], t_secs: float) -> np.ndarray:
    if t_secs <= frames[0].t_secs:
        return frames[0].pose()
    if t_secs >= frames[-1].t_secs:
        return frames[-1].pose()
    i = int(np.searchsorted([k.t_secs for k in frames], t_secs, side="right")) - 1
    a, b = frames[i], frames[i + 1]
    s = (t_secs - a.t_secs) / (b.t_secs - a.t_secs)
    pa, pb = a.pose(), b.pose()
    pose = np.eye(4)
    pose[:3, :3] = pa[:3, :3] @ exp_so3(s * log_so3(pa[:3, :3].T @ pb[:3, :3]))
    pose[:3, 3] = (1 - s) * pa[:3, 3] + s * pb[:3, 3]
    return pose


_SECTIONS: dict[str, type[Any]] = {
    "gripper": GripperSpec,
    "bubble": BubbleSpec,
    "camera": CameraSpec,
    "pattern": PatternSpec,
    "noise": NoiseSpec,
    "membrane": MembraneSpec,
    "support": SupportSpec,
    "load": LoadSpec,
}


def _build(cls: type[Any], values: Any, where: str) -> Any:
    if not isinstance(values, dict):
        raise SceneError(f"{where}: expected a mapping, got {type(values).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise SceneError(f"{where}: unknown field(s) {unknown}; valid: {sorted(names)}")
    try:
        return msgspec.convert(values, cls, strict=False)
    except (msgspec.ValidationError, ValueError) as err:
        raise SceneError(f"{where}: {err}") from err


def scene_from_dict(data: Any, *, path: str = "<dict>") -> Scene:
    """Build and check a scene from a parsed YAML mapping.

    Raises:
        SceneError: the message names ``path`` and the offending field.
    """
    if not isinstance(data, dict):
        raise SceneError(f"{path}: a scene must be a mapping, got {type(data).__name__}")
    data = dict(data)
    known = {f.name for f in fields(Scene)} - {"path"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise SceneError(f"{path}: unknown field(s) {unknown}; valid: {sorted(known)}")
    if "name" not in data:
        data["name"] = Path(path).stem
    if "object" not in data:
        raise SceneError(f"{path}: `object` is required (e.g. {{name: mug}})")
    obj = data["object"]
    if isinstance(obj, str):
        obj = {"name": obj}
    if not isinstance(obj, dict) or "name" not in obj:
        raise SceneError(f"{path}: object: expected {{name: ..., dims_m: {{...}}}}")
    dims = obj.get("dims_m", {}) or {}
    if not isinstance(dims, dict):
        raise SceneError(f"{path}: object.dims_m: expected a mapping")
    unknown_obj = sorted(set(obj) - {"name", "dims_m", "variant"})
    if unknown_obj:
        raise SceneError(
            f"{path}: object: unknown field(s) {unknown_obj}; valid: dims_m, name, variant"
        )
    variant = obj.get("variant")
    if variant is not None and (isinstance(variant, bool) or not isinstance(variant, int)):
        raise SceneError(f"{path}: object.variant: expected an integer id, got {variant!r}")
    kwargs: dict[str, Any] = {"path": str(path)}
    try:
        kwargs["object"] = ObjectSpec.of(str(obj["name"]), variant, dims)
        kwargs["object"].model()
    except ValueError as err:
        raise SceneError(f"{path}: object: {err}") from err
    if "mount_rpy_deg" in data:
        mount = data["mount_rpy_deg"]
        if not (isinstance(mount, list) and len(mount) == 3):
            raise SceneError(f"{path}: mount_rpy_deg: expected [roll, pitch, yaw] in degrees")
        kwargs["mount_rpy_deg"] = tuple(float(v) for v in mount)
    for key in ("name", "seed", "duration_secs"):
        if key in data:
            kwargs[key] = data[key]
    if "effects" in data:
        effects = data["effects"]
        if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
            raise SceneError(f"{path}: effects: expected a list of names, got {effects!r}")
        try:
            resolve(effects)
        except ValueError as err:
            raise SceneError(f"{path}: effects: {err}") from err
        kwargs["effects"] = tuple(effects)
    if "trajectory" in data:
        frames = data["trajectory"]
        if not isinstance(frames, list) or not frames:
            raise SceneError(f"{path}: trajectory: expected a non-empty list of keyframes")
        kwargs["trajectory"] = tuple(
            _build(Keyframe, f, f"{path}: trajectory[{i}]") for i, f in enumerate(frames)
        )
    for key, cls in _SECTIONS.items():
        if key in data:
            section = dict(data[key] or {})
            if key == "gripper" and "commands" in section:
                cmds = section["commands"] or []
                section["commands"] = tuple(
                    _build(ScriptedCommand, c, f"{path}: gripper.commands[{i}]")
                    for i, c in enumerate(cmds)
                )
                built = _build(
                    cls, {k: v for k, v in section.items() if k != "commands"}, f"{path}: {key}"
                )
                import dataclasses

                kwargs[key] = dataclasses.replace(built, commands=section["commands"])
            else:
                kwargs[key] = _build(cls, section, f"{path}: {key}")
    try:
        return Scene(**kwargs)
    except (ValueError, TypeError) as err:
        raise SceneError(f"{path}: {err}") from err


PROJECT_ROOT = Path(__file__).resolve().parents[1]


def scene_path(path: str | Path) -> Path:
    """Where a scene file is: as given, or, for a relative path that does not exist from
    the working directory, in the project (``scenes/mug_grasp.yaml`` works from any
    directory once the project is installed with ``pip install -e .``)."""
    p = Path(path)
    try:
        if not p.is_absolute() and not p.exists() and (PROJECT_ROOT / p).exists():
            return PROJECT_ROOT / p
    except OSError:  # a name the OS refuses (too long): reading it says so
        pass
    return p


def load_scene(path: str | Path) -> Scene:
    """Load and check a scene file (a regular file, YAML read within the bounds of
    :mod:`messages.files`); see :func:`scene_path`.

    Raises:
        SceneError: unreadable file, bad YAML, or a bad field (named in the message).
    """
    p = scene_path(path)
    try:
        text = read_text(p)
    except OSError as err:
        raise SceneError(f"{str(p)[:200]}: cannot read scene: {err.strerror}") from err
    except ValueError as err:
        raise SceneError(f"{p}: cannot read scene: {err}") from err
    try:
        data = load_yaml(text)
    except yaml.YAMLError as err:
        raise SceneError(f"{p}: bad YAML: {err}") from err
    return scene_from_dict(data, path=str(p))
