"""The video mosaic: what both bubbles sensed at one instant, drawn with OpenCV.

Two columns (left and right bubble), three rows: the depth image (colour-mapped over one
range for the whole video, invalid pixels black), the IR image with the mean shear arrow
and the estimated object's outline projected into that camera (green; the true one from
ground truth in grey), and the contact mask (the contact-patch estimate filled, the
simulator's true mask, published on a ``contact_mask`` output, as a grey contour). Each
panel is labelled with its bubble and what it shows; a legend on the right gives the
depth colour bar in millimetres and what the colours of the other rows mean. A bar on
top gives the time, the grasp and task state, the classifier's best class with its
probability, the pose status, and the moment a still was taken at.

:class:`MosaicState` keeps the latest message of each kind; :meth:`MosaicState.render`
draws it. ``cli.bagview`` renders one frame per camera instant of a bag.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import cv2
import numpy as np

from geometry.camera import PinholeCamera
from messages.base import Message
from messages.types import (
    ClassProbabilities,
    GraspState,
    GripperState,
    GroundTruth,
    MaskImage,
    PoseEstimate,
    ShearEstimate,
    TaskEvent,
    ToFImage,
)
from viz.rerun_log import mask_centroid
from viz.shapes import camera_pose, object_mesh, sensor_from_object

SIDES = ("left", "right")
ROWS = ("depth", "IR", "contact mask")
BAR_PX = 44
LEGEND_PX = 76
FONT = cv2.FONT_HERSHEY_SIMPLEX
ESTIMATE_BGR = (80, 220, 80)
TRUTH_BGR = (190, 190, 190)
ARROW_BGR = (40, 40, 255)


def depth_range(depth_m: np.ndarray) -> tuple[float, float]:
    """The 1st and 99th percentiles of the valid pixels (metres); (0, 0) when none."""
    valid = depth_m[np.isfinite(depth_m) & (depth_m > 0)]
    if not valid.size:
        return 0.0, 0.0
    lo, hi = np.percentile(valid, [1, 99])
    return float(lo), float(hi)


def depth_to_bgr(depth_m: np.ndarray, span_m: tuple[float, float] | None = None) -> np.ndarray:
    """Colour-map a depth image over ``span_m`` (near red, far blue; default: this image's
    :func:`depth_range`); NaN and non-positive pixels black."""
    valid = np.isfinite(depth_m) & (depth_m > 0)
    out = np.zeros((*depth_m.shape, 3), np.uint8)
    if not valid.any():
        return out
    lo, hi = span_m if span_m is not None else depth_range(depth_m)
    scaled = np.clip((depth_m - lo) / max(hi - lo, 1e-6), 0, 1)
    gray = np.where(valid, 255 * (1 - scaled), 0).astype(np.uint8)
    colored = cv2.applyColorMap(gray, cv2.COLORMAP_TURBO)
    out[valid] = colored[valid]
    return out


def put_label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.4) -> None:
    """White text on a dark box at ``origin`` (its top-left corner)."""
    (w, h), base = cv2.getTextSize(text, FONT, scale, 1)
    x, y = origin
    cv2.rectangle(image, (x, y), (x + w + 4, y + h + base + 4), (20, 20, 20), -1)
    cv2.putText(image, text, (x + 2, y + h + 2), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)


def depth_legend(height: int, span_m: tuple[float, float]) -> np.ndarray:
    """The depth colour bar (``LEGEND_PX`` wide): the colour map from near (top) to far,
    ticked in millimetres."""
    panel = np.full((height, LEGEND_PX, 3), 32, np.uint8)
    top, bottom = 22, height - 8
    if bottom - top < 10:
        return panel
    lo, hi = span_m
    ramp = np.linspace(lo, hi, bottom - top, dtype=np.float32)[:, None].repeat(14, axis=1)
    panel[top:bottom, 6:20] = depth_to_bgr(ramp, span_m)
    cv2.putText(panel, "depth mm", (4, 14), FONT, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    for frac in (0.0, 0.5, 1.0):
        y = int(round(top + frac * (bottom - top - 1)))
        cv2.line(panel, (20, y), (24, y), (255, 255, 255), 1)
        label = f"{(lo + frac * (hi - lo)) * 1000:.1f}"
        cv2.putText(panel, label, (26, y + 4), FONT, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    return panel


def text_legend(height: int, lines: list[tuple[str, tuple[int, int, int]]]) -> np.ndarray:
    """A legend panel (``LEGEND_PX`` wide) of coloured lines of text."""
    panel = np.full((height, LEGEND_PX, 3), 32, np.uint8)
    for row, (text, color) in enumerate(lines):
        y = 16 + 14 * row
        if y < height:
            cv2.putText(panel, text, (4, y), FONT, 0.35, color, 1, cv2.LINE_AA)
    return panel


def ir_to_bgr(ir: np.ndarray) -> np.ndarray:
    """An IR amplitude image to 8-bit grey (scaled to its 99th percentile) as BGR."""
    top = float(np.percentile(ir, 99)) if ir.size else 1.0
    gray = np.clip(ir.astype(np.float32) * (255.0 / max(top, 1.0)), 0, 255).astype(np.uint8)
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)


def outline_px(camera: PinholeCamera, vertices_in_sensor: np.ndarray) -> np.ndarray | None:
    """The convex outline (K, 1, 2) int32 of points seen in front of a camera, or None."""
    in_front = vertices_in_sensor[vertices_in_sensor[:, 2] > 1e-4]
    if len(in_front) < 3:
        return None
    uv = camera.project(in_front)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    if len(uv) < 3:
        return None
    limit = 4 * max(camera.width_px, camera.height_px)  # cv2 needs int coordinates
    uv = np.clip(uv, -limit, limit)
    return cv2.convexHull(uv.astype(np.float32)).round().astype(np.int32)


@dataclass
class MosaicState:
    """The latest message of each kind a frame shows (fed in arrival order)."""

    object_name: str = ""
    depth_span_m: tuple[float, float] | None = None  # one colour range for a whole video
    images: dict[str, ToFImage] = field(default_factory=dict)
    masks: dict[str, np.ndarray] = field(default_factory=dict)
    true_masks: dict[str, np.ndarray] = field(default_factory=dict)
    shear: dict[str, ShearEstimate] = field(default_factory=dict)
    width_m: float | None = None
    pose: PoseEstimate | None = None
    truth: GroundTruth | None = None
    classes: ClassProbabilities | None = None
    grasp: GraspState | None = None
    task: TaskEvent | None = None
    stamp_nanos: int = 0
    first_stamp_nanos: int | None = None

    def update(self, topic: str, msg: Message) -> None:
        """Take one message (other types are ignored).

        Images and masks are copied: a message decoded from a bag may be a view on the
        file, which closes before the last frame is drawn.
        """
        if isinstance(msg, ToFImage):
            side = msg.sensor or msg.header.frame_id.removesuffix("_sensor")
            self.images[side] = copy.deepcopy(msg)
            self.stamp_nanos = max(self.stamp_nanos, msg.header.stamp_nanos)
            if self.first_stamp_nanos is None:
                self.first_stamp_nanos = msg.header.stamp_nanos
        elif isinstance(msg, MaskImage):
            side = msg.sensor or msg.header.frame_id.removesuffix("_sensor")
            target = self.true_masks if topic.endswith("/contact_mask") else self.masks
            target[side] = np.array(msg.mask)
        elif isinstance(msg, ShearEstimate):
            self.shear[msg.sensor] = msg
        elif isinstance(msg, GripperState):
            self.width_m = msg.width_m
        elif isinstance(msg, PoseEstimate):
            self.pose = msg
        elif isinstance(msg, GroundTruth):
            self.truth = msg
            self.object_name = self.object_name or msg.object_class
        elif isinstance(msg, ClassProbabilities):
            self.classes = msg
        elif isinstance(msg, GraspState):
            self.grasp = msg
        elif isinstance(msg, TaskEvent):
            self.task = msg

    def panel_size(self) -> tuple[int, int]:
        """``(height, width)`` of one panel: the first image's, or the pico flexx's."""
        for image in self.images.values():
            ref = image.depth_m if image.depth_m.size else image.ir
            return int(ref.shape[0]), int(ref.shape[1])
        return 172, 224

    def _outlines(self, side: str, panel: np.ndarray, camera: PinholeCamera) -> None:
        mesh = object_mesh(self.object_name) if self.object_name else None
        if mesh is None or self.width_m is None:
            return
        poses = []
        if self.truth is not None:
            poses.append((self.truth.tool_from_object, TRUTH_BGR))
        if self.pose is not None and self.pose.status in ("ok", "recovered"):
            poses.append((self.pose.tool_from_object, ESTIMATE_BGR))
        for tool_from_object, color in poses:
            camera_in_tool = camera_pose(side, self.width_m, self.images.get(side))
            pts = mesh.transformed(sensor_from_object(camera_in_tool, tool_from_object))
            hull = outline_px(camera, pts)
            if hull is not None:
                cv2.polylines(panel, [hull], True, color, 1, cv2.LINE_AA)

    def _column(self, side: str, height: int, width: int) -> list[np.ndarray]:
        blank = np.zeros((height, width, 3), np.uint8)
        image = self.images.get(side)
        if image is None:
            return [blank, blank.copy(), blank.copy()]
        shape_ok = image.depth_m.shape == (height, width)
        depth = depth_to_bgr(image.depth_m, self.span(image.depth_m)) if shape_ok else blank
        ir = ir_to_bgr(image.ir) if image.ir.shape == (height, width) else blank.copy()
        camera = PinholeCamera.from_frame(image)
        if camera.shape == (height, width):
            self._outlines(side, ir, camera)
        mask = self.masks.get(side)
        shear = self.shear.get(side)
        if shear is not None and shear.has_reference:
            start = mask_centroid(mask, (height, width))
            end = start + 5.0 * np.asarray(shear.shear_px)
            cv2.arrowedLine(
                ir,
                tuple(int(v) for v in start.round()),
                tuple(int(v) for v in end.round()),
                ARROW_BGR,
                2,
                cv2.LINE_AA,
                tipLength=0.25,
            )
        mask_bgr = blank.copy()
        if mask is not None and mask.shape == (height, width):
            mask_bgr[mask > 0] = 255
        true_mask = self.true_masks.get(side)
        if true_mask is not None and true_mask.shape == (height, width):
            contours, _ = cv2.findContours(
                (true_mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE
            )
            cv2.drawContours(mask_bgr, contours, -1, TRUTH_BGR, 1)
        return [depth, ir, mask_bgr]

    def span(self, depth_m: np.ndarray | None = None) -> tuple[float, float]:
        """The depth colour range: the video's, or else this image's (or the first one's)."""
        if self.depth_span_m is not None:
            return self.depth_span_m
        if depth_m is None:
            depth_m = next((i.depth_m for i in self.images.values() if i.depth_m.size), None)
        return depth_range(depth_m) if depth_m is not None else (0.0, 0.0)

    def status_lines(self) -> tuple[str, str]:
        """The bar's two lines: time, grasp and task; the classifier's best class."""
        t = (self.stamp_nanos - (self.first_stamp_nanos or self.stamp_nanos)) * 1e-9
        grasp = "stable" if self.grasp is not None and self.grasp.stable else "open"
        task = f"{self.task.task}: {self.task.event}" if self.task is not None else "-"
        first = f"t={t:6.2f}s  grasp {grasp}  task {task}"
        if self.classes is not None and self.classes.probabilities.size:
            best = int(np.argmax(self.classes.probabilities))
            label = self.classes.best or self.classes.classes[best]
            second = f"class {label} p={float(self.classes.probabilities[best]):.3f}"
        else:
            second = "class -"
        if self.pose is not None:
            second += f"  pose {self.pose.status} rms {self.pose.residual_rms_m * 1e3:.2f} mm"
        return first, second

    def render(self, scale: int = 2, moment: str = "") -> np.ndarray:
        """The mosaic as a BGR uint8 image, :meth:`size` of it; ``moment``: what a still
        shows (an event), written on the bar."""
        height, width = self.panel_size()
        columns = []
        for side in SIDES:
            panels = self._column(side, height, width)
            columns.append(np.vstack(panels))
        grid = np.hstack(columns)
        if scale != 1:
            grid = cv2.resize(grid, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        ph, pw = height * scale, width * scale
        for col, side in enumerate(SIDES):
            for row, what in enumerate(ROWS):
                put_label(grid, f"{side} {what}", (col * pw + 3, row * ph + 3))
        legend = np.vstack(
            [
                depth_legend(ph, self.span()),
                text_legend(
                    ph,
                    [
                        ("shear x5", ARROW_BGR),
                        ("estimate", ESTIMATE_BGR),
                        ("true", TRUTH_BGR),
                    ],
                ),
                text_legend(ph, [("estimate", (255, 255, 255)), ("true", TRUTH_BGR)]),
            ]
        )
        grid = np.hstack([grid, legend])
        bar = np.full((BAR_PX, grid.shape[1], 3), 32, np.uint8)
        for row, text in enumerate(self.status_lines()):
            cv2.putText(bar, text, (6, 18 + 20 * row), FONT, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        if moment:
            (w, _), _ = cv2.getTextSize(moment, FONT, 0.5, 1)
            x = grid.shape[1] - w - 6
            cv2.putText(bar, moment, (x, 38), FONT, 0.5, (0, 220, 255), 1, cv2.LINE_AA)
        return np.vstack([bar, grid])

    def size(self, scale: int = 2) -> tuple[int, int]:
        """``(height, width)`` of :meth:`render`'s image."""
        height, width = self.panel_size()
        return BAR_PX + 3 * height * scale, 2 * width * scale + LEGEND_PX
