"""Geometry of the Soft-bubble gripper: bubble membranes, plates and camera mounts.

Frames (poses are 4x4 float64 homogeneous matrices, ``a_from_b``):

* ``tool`` (T): origin midway between the centres of the two bubble plates; x from the
  right finger to the left finger (the closing direction of the left finger is -x);
  z along the approach direction, out of the palm towards the finger tips;
  y = z cross x. Right-handed.
* ``finger`` (F, one per side): origin at the centre of that finger's acrylic plate;
  x along the plate's inward normal (towards the other finger), z = tool z (towards
  the tip), y = z cross x. For the left finger F's x is tool -x and F's y is tool -y;
  for the right finger F's axes equal the tool's.
* ``left_sensor`` / ``right_sensor``: the internal ToF camera (see ``geometry.camera``):
  z along the optical axis, x along image columns, y along image rows.

The opening ``width_m`` is the WSG 50 jaw opening (docs/facts.md: 0-110 mm). Each finger
mounts its plate ``plate_outset_m`` outboard of its jaw face, so the plates' centres sit
at tool x = +-(width_m / 2 + plate_outset_m): a 110 mm opening leaves room for an 80 mm
mug between two 25 mm bubbles.

The membrane at rest is an ellipsoid cap (docs/facts.md: Drake's bubble uses semi-axes
41.65 x 41.65 x 62.5 mm): in F, ``((x + c) / a_n)^2 + (y / a_t)^2 + (z / a_l)^2 = 1`` with
``x >= 0`` and ``c = a_n - cap_height_m``; the cap protrudes ``cap_height_m`` from the
plate and its footprint on the plate is an ellipse.

The camera sits behind the plate (``camera_back_m`` outward of it), towards the palm
(``camera_z_m`` < 0 along F's z), and its optical axis is tilted ``camera_pitch_deg`` from
the plate normal towards the finger tip: the paper's angled short-range sensor, which
sees the centre and the tips of the fingers where contact happens most. Image columns
run along the finger (the wider 62 degree field of view covers the bubble's length).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

SIDES = ("left", "right")


def _check_side(side: str) -> None:
    if side not in SIDES:
        raise ValueError(f"`side` must be 'left' or 'right', got {side!r}")


@dataclass(frozen=True, kw_only=True)
class BubbleGeometry:
    """The rest shape of one membrane: an ellipsoid cap on a flat plate (frame F).

    Attributes:
        semi_axis_normal_m: ellipsoid semi-axis along the plate normal (F x).
        semi_axis_lateral_m: semi-axis across the finger (F y).
        semi_axis_length_m: semi-axis along the finger (F z).
        cap_height_m: how far the membrane apex protrudes from the plate.
    """

    semi_axis_normal_m: float = 0.04165
    semi_axis_lateral_m: float = 0.04165
    semi_axis_length_m: float = 0.0625
    cap_height_m: float = 0.025

    def __post_init__(self) -> None:
        for name in (
            "semi_axis_normal_m",
            "semi_axis_lateral_m",
            "semi_axis_length_m",
            "cap_height_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be > 0, got {value!r}")
        if self.cap_height_m > self.semi_axis_normal_m:
            raise ValueError(
                f"`cap_height_m` must be <= semi_axis_normal_m ({self.semi_axis_normal_m}),"
                f" got {self.cap_height_m!r}"
            )

    @property
    def center_offset_m(self) -> float:
        """``c``: how far behind the plate the ellipsoid's centre lies."""
        return self.semi_axis_normal_m - self.cap_height_m

    @property
    def semi_axes_m(self) -> np.ndarray:
        """``(a_n, a_t, a_l)`` as an array."""
        return np.array(
            [self.semi_axis_normal_m, self.semi_axis_lateral_m, self.semi_axis_length_m]
        )

    def footprint_semi_axes_m(self) -> tuple[float, float]:
        """Semi-axes (lateral, length) of the ellipse where the cap meets the plate."""
        scale = math.sqrt(1.0 - (self.center_offset_m / self.semi_axis_normal_m) ** 2)
        return self.semi_axis_lateral_m * scale, self.semi_axis_length_m * scale

    def height_m(self, y_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
        """Rest membrane height above the plate (F x) at plate coordinates; NaN off the cap."""
        q = 1.0 - (np.asarray(y_m) / self.semi_axis_lateral_m) ** 2
        q = q - (np.asarray(z_m) / self.semi_axis_length_m) ** 2
        with np.errstate(invalid="ignore"):
            h = self.semi_axis_normal_m * np.sqrt(q) - self.center_offset_m
        return np.where(h >= 0, h, np.nan)

    def volume_m3(self) -> float:
        """Air volume enclosed between the rest cap and the plate."""
        a, h = self.semi_axis_normal_m, self.cap_height_m
        return (
            math.pi
            * self.semi_axis_lateral_m
            * self.semi_axis_length_m
            * h
            * h
            * (3 * a - h)
            / (3 * a * a)
        )

    def intersect_rays(self, origins_f: np.ndarray, directions_f: np.ndarray) -> np.ndarray:
        """Distance along each ray (in F) to the rest membrane; NaN where it misses the cap.

        Rays start inside the ellipsoid (the camera lies inside it), so the forward root
        is unique; a hit behind the plate (F x < 0) is the finger housing, not membrane.

        Args:
            origins_f: ``(..., 3)`` ray origins in F (broadcastable).
            directions_f: ``(..., 3)`` ray directions in F (any length).

        Returns:
            ``(...)`` ray parameter t (in units of the direction's length), NaN on a miss.
        """
        scale = 1.0 / self.semi_axes_m
        o = (np.asarray(origins_f, dtype=np.float64) + [self.center_offset_m, 0.0, 0.0]) * scale
        d = np.asarray(directions_f, dtype=np.float64) * scale
        a = np.sum(d * d, axis=-1)
        b = np.sum(o * d, axis=-1)
        c = np.sum(o * o, axis=-1) - 1.0
        disc = b * b - a * c
        with np.errstate(invalid="ignore"):
            t = (-b + np.sqrt(disc)) / a
        x = np.asarray(origins_f)[..., 0] + t * np.asarray(directions_f)[..., 0]
        return np.where((disc >= 0) & (t > 0) & (x >= 0), t, np.nan)

    def surface_samples(self, spacing_m: float = 0.003) -> SurfaceSamples:
        """Points of the rest cap on a plate grid, with outward normals and area weights."""
        return _surface_samples(self, spacing_m)


@dataclass(frozen=True)
class SurfaceSamples:
    """Samples of the rest membrane in F: points, outward unit normals, areas (m^2)."""

    points_f: np.ndarray
    normals_f: np.ndarray
    area_m2: np.ndarray


@functools.cache
def _surface_samples(bubble: BubbleGeometry, spacing_m: float) -> SurfaceSamples:
    fy, fz = bubble.footprint_semi_axes_m()
    ys = np.arange(-fy + spacing_m / 2, fy, spacing_m)
    zs = np.arange(-fz + spacing_m / 2, fz, spacing_m)
    y, z = (g.ravel() for g in np.meshgrid(ys, zs))
    x = bubble.height_m(y, z)
    keep = np.isfinite(x)
    y, z, x = y[keep], z[keep], x[keep]
    an, at, al = bubble.semi_axes_m
    # Gradient of the implicit ellipsoid: the outward normal of the cap.
    grad = np.stack([(x + bubble.center_offset_m) / an**2, y / at**2, z / al**2], axis=-1)
    normals = grad / np.linalg.norm(grad, axis=-1, keepdims=True)
    # dA = dy dz / |n_x| for a graph x(y, z) over the plate.
    area = spacing_m * spacing_m / normals[:, 0]
    points = np.stack([x, y, z], axis=-1)
    for arr in (points, normals, area):
        arr.setflags(write=False)
    return SurfaceSamples(points, normals, area)


@dataclass(frozen=True, kw_only=True)
class GripperGeometry:
    """Both fingers: the bubble shape, where the plates sit, where the cameras look.

    Attributes:
        bubble: membrane rest shape (the same on both fingers).
        plate_outset_m: plate centre outboard of the jaw face (see module docstring).
        camera_back_m: camera centre behind the plate (outward, along -F x).
        camera_z_m: camera centre along F z (negative: towards the palm).
        camera_pitch_deg: optical axis tilt from the plate normal towards the tip.
        max_width_m: the WSG 50 stroke (docs/facts.md: 110 mm).
    """

    bubble: BubbleGeometry = field(default_factory=BubbleGeometry)
    plate_outset_m: float = 0.02
    camera_back_m: float = 0.02
    camera_z_m: float = -0.035
    camera_pitch_deg: float = 35.0
    max_width_m: float = 0.11

    def __post_init__(self) -> None:
        for name in ("plate_outset_m", "camera_back_m", "max_width_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"`{name}` must be >= 0, got {value!r}")
        if not math.isfinite(self.camera_z_m):
            raise ValueError(f"`camera_z_m` must be finite, got {self.camera_z_m!r}")
        if not -80.0 <= self.camera_pitch_deg <= 80.0:
            raise ValueError(
                f"`camera_pitch_deg` must be in [-80, 80], got {self.camera_pitch_deg!r}"
            )

    def plate_x_m(self, width_m: float) -> float:
        """Tool x of the left plate's centre (the right one is its negative)."""
        return width_m / 2.0 + self.plate_outset_m

    def tool_from_finger(self, side: str, width_m: float) -> np.ndarray:
        """Pose of a finger's plate frame F in the tool frame at opening ``width_m``."""
        _check_side(side)
        pose = np.eye(4)
        x = self.plate_x_m(width_m)
        if side == "left":
            pose[:3, :3] = np.diag([-1.0, -1.0, 1.0])
            pose[0, 3] = x
        else:
            pose[0, 3] = -x
        return pose

    def finger_from_sensor(self) -> np.ndarray:
        """Pose of the camera in its finger's frame F (the same on both fingers)."""
        return _finger_from_sensor(self.camera_back_m, self.camera_z_m, self.camera_pitch_deg)

    def tool_from_sensor(self, side: str, width_m: float) -> np.ndarray:
        """Pose of ``side``'s camera in the tool frame at opening ``width_m``."""
        return self.tool_from_finger(side, width_m) @ self.finger_from_sensor()


@functools.cache
def _finger_from_sensor(back_m: float, z_m: float, pitch_deg: float) -> np.ndarray:
    theta = math.radians(pitch_deg)
    x_f = np.array([1.0, 0.0, 0.0])
    z_f = np.array([0.0, 0.0, 1.0])
    axis_z = math.cos(theta) * x_f + math.sin(theta) * z_f
    axis_x = -math.sin(theta) * x_f + math.cos(theta) * z_f
    axis_y = np.cross(axis_z, axis_x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([axis_x, axis_y, axis_z], axis=1)
    pose[:3, 3] = [-back_m, 0.0, z_m]
    pose.setflags(write=False)
    return pose


DEFAULT_GRIPPER = GripperGeometry()


def tool_from_sensor(
    side: str, width_m: float, geometry: GripperGeometry = DEFAULT_GRIPPER
) -> np.ndarray:
    """Pose (4x4) of ``side``'s ToF camera in the tool frame at jaw opening ``width_m``.

    See the module docstring for the frames. Returns a fresh writable array.
    """
    return np.array(geometry.tool_from_sensor(side, width_m))
