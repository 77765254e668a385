"""Messages as Rerun archetypes, in the gripper's frames.

Entity tree (one recording; the timeline ``stamp`` is each message's header stamp):

* ``tool``: the gripper tool frame, the 3D space.
* ``tool/{side}_sensor``: the bubble camera: ``Transform3D`` (the ``tool_from_sensor``
  its frames carry; for frames that carry none, the CAD mount at the gripper's measured
  opening) and ``Pinhole`` (its intrinsics, RDF: x right, y down, z
  forward); under it, 2D in its image: ``depth`` (``DepthImage``, metres, ``meter=1``),
  ``ir`` (``Image``), ``shear`` (``Arrows2D``: the mean shear from the mask's centroid),
  ``mask/{node}`` (``SegmentationImage``), ``overlay`` (the shear tracker's drawing).
* ``tool/patch``: the contact-patch cloud (``Points3D``, tool frame, coloured per bubble).
* ``tool/object_estimate`` and ``tool/object_true``: ``Transform3D`` (``tool_from_object``)
  and the object's ``Mesh3D`` (logged once, static, when the object is known).
* ``pressure/{side}``, ``gripper/width_m``, ``gripper/force_n``, ``shear/{side}/magnitude_px``,
  ``pose/residual_rms_m``, ``pose/solve_secs``, ``classifier/{class}``: ``Scalars``.
* ``events/grasp``, ``events/task``, ``events/pose``, ``events/classifier``,
  ``events/slip``: ``TextLog``.
* ``wrench/object_force_n/{x,y,z}``, ``wrench/object_torque_nm/{x,y,z}``,
  ``contact/{side}/area_m2``, ``contact/{side}/pressure_rise_pa``, ``slip/{side}/use``:
  ``Scalars``; ``tool/object_force``: the object force as an ``Arrows3D`` (1 cm per N).

Message types the logger does not draw (the simulator's ``WorldState``, commands) are
counted in :attr:`RerunLogger.skipped`.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import rerun as rr

from messages.base import Message
from messages.force import BubbleContact, SlipState, WrenchEstimate
from messages.sim import PlacementTruth
from messages.types import (
    ClassProbabilities,
    ContactPatch,
    GraspState,
    GripperState,
    GroundTruth,
    MaskImage,
    OverlayImage,
    PoseEstimate,
    Pressure,
    ShearEstimate,
    TaskEvent,
    ToFImage,
    pose_is_known,
)
from viz.display import require_display
from viz.shapes import camera_pose, object_mesh

TIMELINE = "stamp"
BUBBLE_COLORS = np.array([[66, 135, 245], [245, 130, 48]], dtype=np.uint8)  # left, right
ESTIMATE_COLOR = (80, 200, 120, 160)
TRUTH_COLOR = (200, 200, 200, 90)
FORCE_ARROW_M_PER_N = 0.01  # the object force drawn 1 cm per newton from the tool origin
FORCE_RGB = (230, 60, 200)
WIDTH_STEP_M = 1e-4  # re-log the camera poses when the opening moves more than this


def mask_centroid(mask: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """Where a shear arrow starts: the mask's centroid, or the image centre (u, v)."""
    if mask is not None and mask.shape == shape[:2] and np.any(mask):
        rows, cols = np.nonzero(mask)
        return np.array([cols.mean(), rows.mean()])
    return np.array([(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0])


VIEWER_PORT = 9876  # Rerun's own default: a viewer already open there is reused


VIEWER_SETTLE_SECS = 3.0  # a viewer that fails to open its window has exited by then


def spawn_viewer(rec: rr.RecordingStream, *, instead: str) -> subprocess.Popen[bytes] | None:
    """Stream ``rec`` to a Rerun viewer: the one already listening on ``VIEWER_PORT``
    (returns None), or a new one started here (returns its process, which outlives this
    one unless Ctrl-C reaches both). Started directly rather than with ``rr.spawn``, whose
    wait for the viewer's port holds the interpreter (no Ctrl-C, no SIGTERM) for seconds,
    so that :func:`flush` can tell when the window is gone.

    The viewer is the ``rerun`` executable installed next to this Python (``rerun-sdk``
    puts it there), so it is found without an activated virtual environment; what it
    prints goes to a temporary file, shown when it fails.

    Raises:
        viz.display.NoDisplay: there is no display; the message ends with ``instead``.
        OSError: no ``rerun`` executable.
    """
    require_display(instead)
    url = f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"
    with socket.socket() as probe:
        if probe.connect_ex(("127.0.0.1", VIEWER_PORT)) == 0:
            rec.connect_grpc(url)
            return None
    beside = Path(sys.executable).with_name("rerun")
    exe = str(beside) if beside.is_file() else shutil.which("rerun")
    if exe is None:
        raise OSError("no Rerun viewer here: `rerun` (from rerun-sdk) is not installed")
    log = tempfile.TemporaryFile()
    viewer = subprocess.Popen(
        [exe, f"--port={VIEWER_PORT}", "--memory-limit=75%", "--expect-data-soon"],
        stdout=log,
        stderr=log,
        env=dict(os.environ, RERUN_APP_ONLY="true"),
    )
    viewer.log = log  # type: ignore[attr-defined]
    rec.connect_grpc(url)
    return viewer


def flush(
    rec: rr.RecordingStream,
    deadline_secs: float | None = None,
    viewer: subprocess.Popen[bytes] | None = None,
) -> bool:
    """Flush ``rec`` in short waits, so that Ctrl-C and SIGTERM are handled between them
    (one long wait inside Rerun holds the interpreter: a viewer that went away made it
    wait for good). Returns False when ``deadline_secs`` passed first.

    Raises:
        OSError: ``viewer`` (from :func:`spawn_viewer`) exited before it took the data;
            the message ends with the last line it printed.
    """
    start = time.monotonic()
    while True:
        try:
            rec.flush(timeout_sec=0.25)
            return True
        except RuntimeError:  # timed out; signals run now
            check_viewer(viewer)
            if deadline_secs is not None and time.monotonic() - start > deadline_secs:
                return False


def confirm_viewer(
    viewer: subprocess.Popen[bytes] | None, settle_secs: float = VIEWER_SETTLE_SECS
) -> None:
    """After the last flush: a viewer started here that exits within ``settle_secs`` did
    not show the data, though it may have taken it (one that cannot open its display can
    accept a small recording before it fails, and the write error stays inside Rerun).
    Raise ``OSError`` as :func:`check_viewer` does; a viewer still up returns at once
    after ``settle_secs``."""
    if viewer is None:
        return
    try:
        viewer.wait(timeout=settle_secs)
    except subprocess.TimeoutExpired:
        return
    check_viewer(viewer)


def check_viewer(viewer: subprocess.Popen[bytes] | None) -> None:
    """Raise ``OSError`` (with the last line it printed) if ``viewer`` has exited."""
    if viewer is not None and viewer.poll() is not None:
        raise OSError(
            f"the Rerun viewer exited (code {viewer.returncode}) before it took the data: "
            f"{_last_line(viewer)}"
        )


def _last_line(viewer: subprocess.Popen[bytes]) -> str:
    log = getattr(viewer, "log", None)
    if log is None:
        return "(no output)"
    log.seek(0)
    lines = [ln for ln in log.read().decode(errors="replace").splitlines() if ln.strip()]
    return re.sub(r"\x1b\[[0-9;]*m", "", lines[-1]).strip() if lines else "(no output)"


def _owned(array: np.ndarray) -> np.ndarray:
    """A C-contiguous array owning its memory: Rerun's Arrow import needs aligned buffers,
    and a decoded frame's arrays are views at any offset of the received bytes."""
    return np.require(array, requirements=["C", "A", "O"])


def _sensor(name: str, frame_id: str) -> str:
    side = name or frame_id.removesuffix("_sensor")
    return side if side in ("left", "right") else "left"


class RerunLogger:
    """Logs decoded messages into one :class:`rerun.RecordingStream`.

    Args:
        rec: the recording (a file sink, a spawned viewer, or a memory recording).
        object_name: the object to draw under the estimated pose until a ground truth or
            a classification names one ("" for none).
        arrow_gain: shear arrows are drawn this many times their length in pixels.
    """

    def __init__(self, rec: rr.RecordingStream, *, object_name: str = "", arrow_gain: float = 5.0):
        self.rec = rec
        self.object_name = object_name
        self.arrow_gain = arrow_gain
        self.width_m: float | None = None
        self.masks: dict[str, np.ndarray] = {}
        self.shapes: dict[str, tuple[int, int]] = {}
        self.intrinsics: dict[str, tuple[float, ...]] = {}
        self.placed: set[str] = set()  # sides whose frames carry their camera pose
        self.pose_status = "ok"
        self.meshes_logged: set[tuple[str, str]] = set()
        self.logged: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()

    def log(self, topic: str, msg: Message) -> None:
        """Log one message received on ``topic`` (its type picks the archetypes)."""
        handler = getattr(self, f"_log_{type(msg).__name__}", None)
        if handler is None:
            self.skipped[type(msg).__name__] += 1
            return
        stamp = int(getattr(getattr(msg, "header", None), "stamp_nanos", 0))
        self.rec.set_time(TIMELINE, timestamp=np.datetime64(stamp, "ns"))
        handler(topic, msg)
        self.logged[type(msg).__name__] += 1

    # -- images --------------------------------------------------------------------------------

    def _log_ToFImage(self, topic: str, msg: ToFImage) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        base = f"tool/{side}_sensor"
        if pose_is_known(msg.tool_from_sensor):
            self.placed.add(side)
            self._camera(side, camera_pose(side, 0.0, msg))
        image = msg.depth_m if msg.depth_m.size else msg.ir
        height, width = image.shape
        self.shapes[side] = (height, width)
        intrinsics = (msg.fx_px, msg.fy_px, msg.cx_px, msg.cy_px, width, height)
        if self.intrinsics.get(side) != intrinsics:
            self.intrinsics[side] = intrinsics
            self.rec.log(
                base,
                rr.Pinhole(
                    focal_length=[msg.fx_px, msg.fy_px],
                    principal_point=[msg.cx_px, msg.cy_px],
                    width=width,
                    height=height,
                    camera_xyz=rr.ViewCoordinates.RDF,
                    image_plane_distance=0.03,
                ),
            )
        if msg.depth_m.size:
            self.rec.log(f"{base}/depth", rr.DepthImage(_owned(msg.depth_m), meter=1.0))
        if msg.ir.size:
            self.rec.log(f"{base}/ir", rr.Image(_owned(msg.ir), color_model="L"))

    def _log_MaskImage(self, topic: str, msg: MaskImage) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        node = topic.split("/")[0] or "mask"
        self.masks[side] = msg.mask
        self.rec.log(
            f"tool/{side}_sensor/mask/{node}", rr.SegmentationImage((msg.mask > 0).astype(np.uint8))
        )

    def _log_OverlayImage(self, topic: str, msg: OverlayImage) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        self.rec.log(f"overlay/{side}", rr.Image(_owned(msg.image), color_model="BGR"))

    def _log_ShearEstimate(self, topic: str, msg: ShearEstimate) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        shape = self.shapes.get(side)
        if shape is not None:
            origin = mask_centroid(self.masks.get(side), shape)
            vector = np.asarray(msg.shear_px, dtype=np.float64) * self.arrow_gain
            self.rec.log(
                f"tool/{side}_sensor/shear",
                rr.Arrows2D(origins=[origin], vectors=[vector], colors=[(255, 40, 40)]),
            )
        self.rec.log(f"shear/{side}/magnitude_px", rr.Scalars([msg.magnitude_px]))

    # -- 3D ------------------------------------------------------------------------------------

    def _log_GripperState(self, topic: str, msg: GripperState) -> None:
        self.rec.log("gripper/width_m", rr.Scalars([msg.width_m]))
        self.rec.log("gripper/force_n", rr.Scalars([msg.force_n]))
        if self.width_m is None or abs(msg.width_m - self.width_m) > WIDTH_STEP_M:
            self.width_m = msg.width_m
            for side in ("left", "right"):
                if side not in self.placed:
                    self._camera(side, camera_pose(side, msg.width_m))

    def _camera(self, side: str, pose: np.ndarray) -> None:
        self.rec.log(
            f"tool/{side}_sensor", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3])
        )

    def _log_ContactPatch(self, topic: str, msg: ContactPatch) -> None:
        colors = BUBBLE_COLORS[np.minimum(msg.bubble, 1)]
        self.rec.log(
            "tool/patch", rr.Points3D(_owned(msg.points_in_tool), colors=colors, radii=0.0008)
        )

    def _object(self, entity: str, name: str, pose: np.ndarray, color: tuple[int, ...]) -> None:
        self.rec.log(entity, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        mesh = object_mesh(name) if name else None
        if mesh is not None and (entity, name) not in self.meshes_logged:
            self.meshes_logged.add((entity, name))
            self.rec.log(
                f"{entity}/mesh",
                rr.Mesh3D(
                    vertex_positions=mesh.vertices,
                    triangle_indices=mesh.triangles,
                    albedo_factor=color,
                ),
                static=True,
            )

    def _log_PoseEstimate(self, topic: str, msg: PoseEstimate) -> None:
        if msg.status in ("ok", "recovered"):
            self._object(
                "tool/object_estimate", self.object_name, msg.tool_from_object, ESTIMATE_COLOR
            )
        self.rec.log("pose/residual_rms_m", rr.Scalars([msg.residual_rms_m]))
        self.rec.log("pose/solve_secs", rr.Scalars([msg.solve_secs]))
        if msg.status != self.pose_status:
            ok = msg.status in ("ok", "recovered")
            level = rr.TextLogLevel.INFO if ok else rr.TextLogLevel.WARN
            self.rec.log("events/pose", rr.TextLog(f"pose {msg.status}", level=level))
            self.pose_status = msg.status

    def _log_GroundTruth(self, topic: str, msg: GroundTruth) -> None:
        if not self.object_name:
            self.object_name = msg.object_class
        self._object("tool/object_true", msg.object_class, msg.tool_from_object, TRUTH_COLOR)

    # -- time series and events ----------------------------------------------------------------

    def _log_Pressure(self, topic: str, msg: Pressure) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        self.rec.log(f"pressure/{side}", rr.Scalars([msg.pressure_pa]))

    def _log_GraspState(self, topic: str, msg: GraspState) -> None:
        self.rec.log("grasp/stable", rr.Scalars([float(msg.stable)]))
        if msg.event:
            self.rec.log("events/grasp", rr.TextLog(f"grasp {msg.event}"))

    def _log_TaskEvent(self, topic: str, msg: TaskEvent) -> None:
        text = f"{msg.task}: {msg.event}" + (f" ({msg.detail})" if msg.detail else "")
        self.rec.log("events/task", rr.TextLog(text))

    def _log_PlacementTruth(self, topic: str, msg: PlacementTruth) -> None:
        outcome = "placed" if msg.placed else "dropped"
        text = (
            f"world: {outcome} (gap {msg.gap_m * 1000:.1f} mm, pushed {msg.push_m * 1000:.1f} mm"
            f" past contact, tilt {msg.tilt_deg:.1f} deg)"
        )
        self.rec.log("events/task", rr.TextLog(text))

    def _log_ClassProbabilities(self, topic: str, msg: ClassProbabilities) -> None:
        for name, p in zip(msg.classes, msg.probabilities.tolist(), strict=True):
            self.rec.log(f"classifier/{name}", rr.Scalars([p]))
        best = int(np.argmax(msg.probabilities)) if msg.probabilities.size else -1
        if best >= 0:
            label = msg.best or msg.classes[best]
            self.rec.log(
                "events/classifier",
                rr.TextLog(f"{label} p={float(msg.probabilities[best]):.3f}"),
            )

    # -- force and slip ------------------------------------------------------------------------

    def _log_WrenchEstimate(self, topic: str, msg: WrenchEstimate) -> None:
        force = np.asarray(msg.object_force_n, dtype=np.float64)
        for axis, value in zip("xyz", force.tolist(), strict=True):
            self.rec.log(f"wrench/object_force_n/{axis}", rr.Scalars([value]))
        for axis, value in zip("xyz", np.asarray(msg.object_torque_nm).tolist(), strict=True):
            self.rec.log(f"wrench/object_torque_nm/{axis}", rr.Scalars([value]))
        self.rec.log(
            "tool/object_force",
            rr.Arrows3D(
                origins=[[0.0, 0.0, 0.0]], vectors=[force * FORCE_ARROW_M_PER_N], colors=[FORCE_RGB]
            ),
        )

    def _log_BubbleContact(self, topic: str, msg: BubbleContact) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        self.rec.log(f"contact/{side}/area_m2", rr.Scalars([msg.area_m2]))
        self.rec.log(f"contact/{side}/pressure_rise_pa", rr.Scalars([msg.pressure_rise_pa]))

    def _log_SlipState(self, topic: str, msg: SlipState) -> None:
        side = _sensor(msg.sensor, msg.header.frame_id)
        self.rec.log(f"slip/{side}/use", rr.Scalars([msg.use]))
        if msg.onset:
            self.rec.log(
                "events/slip",
                rr.TextLog(f"{side} bubble slips ({msg.onset})", level=rr.TextLogLevel.WARN),
            )
