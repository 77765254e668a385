"""The emulated rig: every device of ``graphs/hardware.yaml`` emulated, driven by one world.

``launch.py graphs/hardware.yaml --emulate [--rig FILE]`` runs the hardware graph's own
driver nodes against these emulators (``sim.rig_launch`` rewires the graph):

* the WSG 50 is ``sim.wsg50_server``, served by ``world.sim`` on its jaws;
* each MCP2221A bridge with its ABP sensor is :class:`WorldBridge`, behind a pyusb backend
  (:func:`usb_backend`, ``sim.mcp2221_emulator``): its readings follow the world's bubble
  pressure through the as-built sensor's offset, gain error and noise;
* each pico flexx is :class:`CameraEmulator` behind the royale SDK stand-in
  (``sim/royale_sdk/roypy.py``): frames rendered by the simulator at the use case's frame
  rate from the as-built camera (its mount off the CAD one, its own intrinsics), in the
  SDK's layout (x, y, z, noise, gray, confidence per pixel; confidence 0 where invalid).

The world publishes its states (``WorldState``, the graph's own codec) on a ZeroMQ
endpoint, the *feed*; the emulators in the driver nodes' processes subscribe to it. The
session file named by ``$SOFTBUBBLE_EMULATED_RIG`` (JSON) says where the feed is, which
as-built rig file to model and the folder of *plugs*: a file ``unplugged/<device>`` there
unplugs that device (``left_camera``, ``left_pressure``, ...) until it is removed.

An as-built rig file (``rigs/*.yaml``, :func:`load_rig`)::

    rig: asbuilt-example
    cameras:
      left: {camera_id: EMU-CAM-L, rpy_deg: [1.0, -0.5, 1.2], xyz_mm: [1.2, -0.8, 0.9],
             intrinsics: {fx: 205.0, fy: 206.1, cx: 113.2, cy: 84.7}}
    pressure:
      left: {serial: EMU-BUBBLE-L, offset_pa: 35.0, gain: 1.02, noise_pa: 0.3}

A camera's ``rpy_deg``/``xyz_mm`` is its mount error in its own frame (true mount = CAD
mount @ error), at most 3 degrees and 3 mm; missing sections are nominal. A rig file may
also script faults, by the world's clock::

    faults:
      - {device: left_camera, at_secs: 1.2, for_secs: 1.5}    # unplugged, then back
      - {device: right_pressure, at_secs: 1.5, for_secs: 0.6}
      - {device: gripper, at_secs: 0.5}                       # its TCP connection dropped

(``left_camera``/``right_camera`` stop delivering and vanish from the SDK's list; a
``*_pressure`` bridge vanishes from the USB bus; ``gripper``: the WSG 50 closes its
clients' connections once and keeps listening.)
"""

from __future__ import annotations

import json
import math
import os
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
import zmq

from devices.abp import PSI_PA
from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from geometry.se3 import make_pose, rotation_angle
from messages.codec import decode
from messages.sim import WorldState
from sim.mcp2221_emulator import EmulatedBackend, EmulatedBridge, abp_bytes
from sim.scene import Scene, load_scene
from sim.wire import from_message, scene_of

if TYPE_CHECKING:
    from sim.tof import BubbleRenderer

SESSION_ENV = "SOFTBUBBLE_EMULATED_RIG"
MAX_MOUNT_ERROR_DEG = 3.0
MAX_MOUNT_ERROR_MM = 3.0
USE_CASE_FPS = {
    "MODE_9_5FPS_2000": 5.0, "MODE_9_10FPS_1000": 10.0, "MODE_9_15FPS_700": 15.0,
    "MODE_9_25FPS_450": 25.0, "MODE_5_35FPS_600": 35.0, "MODE_5_45FPS_500": 45.0,
}  # fmt: skip
PICO_FLEXX_LENS = {"k1": 0.0, "k2": 0.0, "k3": 0.0, "p1": 0.0, "p2": 0.0}


def rpy_matrix(rpy_deg: Any) -> np.ndarray:
    """Rotation from roll, pitch, yaw in degrees (about x, then y, then z; fixed axes)."""
    r, p, y = (math.radians(float(a)) for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    rot: np.ndarray = rz @ ry @ rx
    return rot


@dataclass(frozen=True)
class AsBuiltCamera:
    """One emulated camera: its id, its mount error (own frame) and its intrinsics."""

    camera_id: str
    mount_error: np.ndarray = field(default_factory=lambda: np.eye(4))
    intrinsics: Mapping[str, float] = field(default_factory=dict)

    def camera(self, nominal: PinholeCamera) -> PinholeCamera:
        k = self.intrinsics
        return PinholeCamera(
            width_px=nominal.width_px,
            height_px=nominal.height_px,
            fx_px=float(k.get("fx", nominal.fx_px)),
            fy_px=float(k.get("fy", nominal.fy_px)),
            cx_px=float(k.get("cx", nominal.cx_px)),
            cy_px=float(k.get("cy", nominal.cy_px)),
        )


@dataclass(frozen=True)
class AsBuiltSensor:
    """One emulated pressure sensor: its bridge's serial; reading = gain * p + offset + noise."""

    serial: str
    offset_pa: float = 0.0
    gain: float = 1.0
    noise_pa: float = 0.0


DEVICES = ("left_camera", "right_camera", "left_pressure", "right_pressure", "gripper")


@dataclass(frozen=True)
class Fault:
    """A scripted fault: ``device`` unplugged (or, the gripper, dropped) from ``at_secs`` of
    world time for ``for_secs`` (0: for good; the gripper's drop is instant)."""

    device: str
    at_secs: float
    for_secs: float = 0.0

    def active(self, t_secs: float) -> bool:
        return t_secs >= self.at_secs and (
            self.for_secs <= 0 or t_secs < self.at_secs + self.for_secs
        )


@dataclass(frozen=True)
class AsBuiltRig:
    """A rig as built (see the module docstring); :data:`NOMINAL` without a file."""

    rig: str = "emulated-nominal"
    cameras: Mapping[str, AsBuiltCamera] = field(
        default_factory=lambda: {s: AsBuiltCamera(f"EMU-CAM-{s[0].upper()}") for s in SIDES}
    )
    pressure: Mapping[str, AsBuiltSensor] = field(
        default_factory=lambda: {s: AsBuiltSensor(f"EMU-BUBBLE-{s[0].upper()}") for s in SIDES}
    )
    source: str = ""
    faults: tuple[Fault, ...] = ()


NOMINAL = AsBuiltRig()


def _num(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: must be a finite number, got {value!r}")
    return float(value)


def _vec3(where: str, value: Any) -> list[float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ValueError(f"{where}: must be a list of 3 numbers, got {value!r}")
    return [_num(where, v) for v in value]


def load_rig(path: str | Path) -> AsBuiltRig:
    """Read an as-built rig file; errors name the file and the field."""
    source = str(path)
    try:
        doc = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise ValueError(f"{source}: cannot read the rig file: {err}") from err
    if not isinstance(doc, dict):
        raise ValueError(f"{source}: must be a mapping")
    cameras = dict(NOMINAL.cameras)
    for side, raw in (doc.get("cameras") or {}).items():
        where = f"{source}: cameras.{side}"
        if side not in SIDES or not isinstance(raw, dict):
            raise ValueError(f"{where}: must be 'left' or 'right' with a mapping")
        rot = rpy_matrix(_vec3(f"{where}.rpy_deg", raw.get("rpy_deg", [0, 0, 0])))
        xyz_mm = np.array(_vec3(f"{where}.xyz_mm", raw.get("xyz_mm", [0, 0, 0])))
        if math.degrees(rotation_angle(rot)) > MAX_MOUNT_ERROR_DEG + 1e-9:
            raise ValueError(f"{where}.rpy_deg: more than {MAX_MOUNT_ERROR_DEG} degrees off")
        if np.linalg.norm(xyz_mm) > MAX_MOUNT_ERROR_MM + 1e-9:
            raise ValueError(f"{where}.xyz_mm: more than {MAX_MOUNT_ERROR_MM} mm off")
        intrinsics = {
            k: _num(f"{where}.intrinsics.{k}", v) for k, v in (raw.get("intrinsics") or {}).items()
        }
        cameras[side] = AsBuiltCamera(
            str(raw.get("camera_id", cameras[side].camera_id)),
            make_pose(rot, xyz_mm / 1000.0),
            intrinsics,
        )
    pressure = dict(NOMINAL.pressure)
    for side, raw in (doc.get("pressure") or {}).items():
        where = f"{source}: pressure.{side}"
        if side not in SIDES or not isinstance(raw, dict):
            raise ValueError(f"{where}: must be 'left' or 'right' with a mapping")
        pressure[side] = AsBuiltSensor(
            str(raw.get("serial", pressure[side].serial)),
            _num(f"{where}.offset_pa", raw.get("offset_pa", 0.0)),
            _num(f"{where}.gain", raw.get("gain", 1.0)),
            _num(f"{where}.noise_pa", raw.get("noise_pa", 0.0)),
        )
    faults = []
    for k, raw in enumerate(doc.get("faults") or []):
        where = f"{source}: faults[{k}]"
        if not isinstance(raw, dict) or raw.get("device") not in DEVICES:
            raise ValueError(f"{where}: `device` must be one of {', '.join(DEVICES)}")
        faults.append(
            Fault(
                raw["device"],
                _num(f"{where}.at_secs", raw.get("at_secs")),
                _num(f"{where}.for_secs", raw.get("for_secs", 0.0)),
            )
        )
    return AsBuiltRig(
        str(doc.get("rig", Path(path).stem)), cameras, pressure, source, tuple(faults)
    )


@dataclass(frozen=True)
class Session:
    """What the launcher told the emulators (``$SOFTBUBBLE_EMULATED_RIG``, JSON)."""

    feed: str
    rig: AsBuiltRig
    plugs: Path
    scene: str

    def plugged(self, device: str, t_secs: float | None = None) -> bool:
        """Whether ``device`` is plugged in: no plug file says otherwise, and no scripted
        fault is on at world time ``t_secs`` (None: the newest state's on the feed)."""
        if (self.plugs / "unplugged" / device).exists():
            return False
        if t_secs is None:
            latest = feed().poll()
            t_secs = None if latest is None else latest.time_secs
        return t_secs is None or not any(
            f.device == device and f.active(t_secs) for f in self.rig.faults
        )


_session: Session | None = None


def forget_session() -> None:
    """Drop this process's session and feed (a new session starts: ``sim.rig_launch``)."""
    global _session, _feed
    if _feed is not None:
        _feed.close()
    _session = _feed = None


def session() -> Session:
    """This process's emulated rig session (read once)."""
    global _session
    if _session is None:
        path = os.environ.get(SESSION_ENV)
        if not path:
            raise RuntimeError(
                f"no emulated rig: ${SESSION_ENV} is not set (run the graph with --emulate)"
            )
        doc = json.loads(Path(path).read_text())
        rig = load_rig(doc["rig"]) if doc.get("rig") else NOMINAL
        _session = Session(doc["feed"], rig, Path(doc["plugs"]), doc["scene"])
    return _session


class WorldFeed:
    """The world's states, as the world node publishes them on the feed (newest kept)."""

    def __init__(self, endpoint: str) -> None:
        self.socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"")
        self.socket.connect(endpoint)
        self.latest: WorldState | None = None
        self._lock = threading.Lock()

    def poll(self, timeout_ms: int = 0) -> WorldState | None:
        """Drain what arrived (waiting up to ``timeout_ms`` for the first); the newest."""
        with self._lock:
            wait = timeout_ms
            while self.socket.poll(wait):
                _, msg = decode(self.socket.recv_multipart(copy=False))
                if isinstance(msg, WorldState):
                    self.latest = msg
                wait = 0
            return self.latest

    def close(self) -> None:
        self.socket.close(0)


_feed: WorldFeed | None = None


def feed() -> WorldFeed:
    """This process's subscription to the session's feed (one per process)."""
    global _feed
    if _feed is None:
        _feed = WorldFeed(session().feed)
    return _feed


def sdk_points(frame_arrays: Mapping[str, np.ndarray], camera: PinholeCamera) -> np.ndarray:
    """A rendered frame in the royale SDK's layout: (height, width, 6) float32 of x, y, z
    (metres, camera frame), noise (metres), gray value and depth confidence (0: invalid,
    else 1..255 falling with the noise); invalid pixels have x = y = z = 0."""
    depth = np.asarray(frame_arrays["depth_m"], np.float32)
    valid = np.isfinite(depth)
    z = np.where(valid, depth, 0.0).astype(np.float32)
    rays = camera.rays()
    noise = np.nan_to_num(np.asarray(frame_arrays.get("noise_m", np.zeros_like(z))), nan=0.0)
    amp = np.nan_to_num(np.asarray(frame_arrays.get("amplitude", np.zeros_like(z))), nan=0.0)
    confidence = np.where(valid, np.clip(255.0 * (1.0 - noise / 0.07), 1.0, 255.0), 0.0)
    pts = np.empty((*z.shape, 6), np.float32)
    pts[..., 0] = rays[..., 0] * z
    pts[..., 1] = rays[..., 1] * z
    pts[..., 2] = z
    pts[..., 3] = np.where(valid, noise, 0.0)
    pts[..., 4] = np.clip(amp, 0.0, 65535.0)
    pts[..., 5] = confidence
    return pts


def as_built_renderer(scene: Scene, side: str, spec: AsBuiltCamera) -> BubbleRenderer:
    """A renderer of ``side``'s camera as built: its true mount and intrinsics."""
    from sim.tof import BubbleRenderer

    nominal = scene.gripper_geometry().finger_from_sensor()
    return BubbleRenderer(
        scene,
        side,
        finger_from_sensor=nominal @ spec.mount_error,
        camera=spec.camera(scene.camera.intrinsics()),
    )


class CameraEmulator:
    """One emulated pico flexx: renders the world's newest state at the use case's rate and
    hands the points to ``deliver(points, stamp_us)`` on its own thread (as the SDK does)."""

    def __init__(self, side: str, spec: AsBuiltCamera, device: str) -> None:
        self.side, self.spec, self.device = side, spec, device
        self.fps = 10.0
        self.deliver: Callable[[np.ndarray, int], None] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._renderers: dict[Any, Any] = {}

    def camera(self) -> PinholeCamera:
        """The intrinsics the camera reports (its as-built ones, at the scene's size)."""
        return self.spec.camera(load_scene(session().scene).camera.intrinsics())

    def start(self, use_case: str, deliver: Callable[[np.ndarray, int], None]) -> None:
        self.fps = USE_CASE_FPS.get(use_case, 10.0)
        self.deliver = deliver
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, name=f"emulated-{self.device}", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._thread = None

    def _renderer(self, msg: WorldState) -> Any:
        scene = scene_of(msg)
        key = (scene.path, scene.seed, tuple(scene.effects))
        if key not in self._renderers:
            self._renderers[key] = as_built_renderer(scene, self.side, self.spec)
        return self._renderers[key]

    def _run(self) -> None:
        # A frame per 1/fps of world time (the first state of each slot), so two cameras
        # at one rate take the same instants, as cameras on one trigger would.
        last_slot = -1
        while not self._stop.is_set():
            msg = feed().poll(timeout_ms=20)
            if msg is None:
                continue
            slot = int(msg.time_secs * self.fps + 1e-6)
            if slot == last_slot or not session().plugged(self.device, msg.time_secs):
                continue  # no new slot; or unplugged: no frames (the driver notices)
            last_slot = slot
            renderer = self._renderer(msg)
            frame = renderer.render(from_message(msg))
            points = sdk_points(frame.arrays, renderer.camera)
            deliver = self.deliver
            if deliver is not None:
                deliver(points, msg.header.stamp_nanos // 1000)


class WorldBridge(EmulatedBridge):
    """An MCP2221A whose ABP sensor reads the world's bubble pressure (as built)."""

    def __init__(self, side: str, spec: AsBuiltSensor, device: str, *, pmax_pa: float) -> None:
        super().__init__(serial=spec.serial, device=device)
        self.side, self.spec, self.pmax_pa = side, spec, pmax_pa
        self.rng = np.random.default_rng(list(spec.serial.encode()))
        # Before the world's first state the bubble is inflated and free.
        self.rest_pa = load_scene(session().scene).bubble.inflation_pa

    def answer(self, report: bytes) -> bytes:
        if report[0] == 0x91:
            msg = feed().poll()
            true_pa = self.rest_pa if msg is None else msg.pressure_pa[SIDES.index(self.side)]
            s = self.spec
            reading = s.gain * true_pa + s.offset_pa + s.noise_pa * self.rng.standard_normal()
            self.sensor_bytes = abp_bytes(reading, pmin_pa=0.0, pmax_pa=self.pmax_pa)
        return super().answer(report)


class RigBackend(EmulatedBackend):
    """The emulated USB bus of the rig: both bridges, unplugged by the session's plugs."""

    def enumerate_devices(self) -> Any:
        for bridge in self.bridges:
            bridge.plugged = session().plugged(bridge.device)
        return super().enumerate_devices()

    def _bridge(self, handle: int) -> EmulatedBridge:
        bridge = self.bridges[handle]
        if not session().plugged(bridge.device):
            bridge.plugged = False
        return super()._bridge(handle)


def usb_backend() -> RigBackend:
    """The pyusb backend of an emulated rig (``devices.mcp2221``'s backend hook names it)."""
    rig = session().rig
    return RigBackend(
        *(
            WorldBridge(side, rig.pressure[side], f"{side}_pressure", pmax_pa=PSI_PA)
            for side in SIDES
        )
    )
