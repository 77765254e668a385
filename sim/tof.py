"""Rendering one bubble's ToF frame from a world snapshot, effect by effect.

:class:`BubbleRenderer` precomputes everything that does not change between frames
(per-pixel rays in the sensor and finger frames, the rest membrane's range and
incidence, the ray-to-plate distances, the low-resolution grid the object field is
evaluated on, the dot texture) and then runs only the camera effects the scene
resolves to (``sim.effects``), in order, each adding its named arrays to the frame.
:attr:`BubbleRenderer.calls` counts the evaluations of each effect, so tests can check
that an effect that is off was not paid for.

The library entry points (no runtime) are in ``sim/__init__.py``: :func:`sim.render`
(a scene at a time), :func:`sim.render_grasp` (an object, a pose and an opening) and
:class:`sim.Simulator` (step a scene frame by frame).
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from geometry.camera import PinholeCamera
from geometry.se3 import invert
from messages.base import Header
from messages.types import MaskImage, ToFImage
from sim.effects import EFFECTS, camera_effects
from sim.friction import slip_shift_m, stiffening
from sim.membrane import CulledField, Tension, cull_to_bounds, march_to_surface
from sim.scene import Scene
from sim.world import WorldSnapshot

SIDE_INDEX = {"left": 0, "right": 1}
_EMPTY_F32 = np.zeros((0, 0), np.float32)
_EMPTY_U16 = np.zeros((0, 0), np.uint16)


@dataclass
class BubbleFrame:
    """What the camera effects produced for one bubble at one instant."""

    side: str
    arrays: dict[str, np.ndarray]
    tool_from_sensor: np.ndarray  # 4x4, the camera in the tool frame at this opening

    def tof_image(self, camera: Any, stamp_nanos: int) -> ToFImage:
        """The wire message: depth (float32, NaN invalid) and IR (uint16), or empty arrays
        for channels whose effect is off."""
        depth = self.arrays.get("depth_m")
        amp = self.arrays.get("amplitude")
        ir = _EMPTY_U16
        if amp is not None:
            ir = np.clip(np.nan_to_num(amp, nan=0.0), 0.0, 65535.0).round().astype(np.uint16)
        return ToFImage(
            header=Header(stamp_nanos=stamp_nanos, frame_id=f"{self.side}_sensor"),
            sensor=self.side,
            depth_m=_EMPTY_F32 if depth is None else depth,
            ir=ir,
            fx_px=camera.fx_px,
            fy_px=camera.fy_px,
            cx_px=camera.cx_px,
            cy_px=camera.cy_px,
            tool_from_sensor=self.tool_from_sensor,
        )

    def contact_mask(self, stamp_nanos: int) -> MaskImage:
        """The true contact patch (255 where the membrane is indented)."""
        contact = self.arrays["contact"]
        return MaskImage(
            header=Header(stamp_nanos=stamp_nanos, frame_id=f"{self.side}_sensor"),
            sensor=self.side,
            mask=(contact.astype(np.uint8) * 255),
        )


class BubbleRenderer:
    """Renders one bubble of one scene (see the module docstring)."""

    def __init__(
        self,
        scene: Scene,
        side: str,
        *,
        finger_from_sensor: np.ndarray | None = None,
        camera: PinholeCamera | None = None,
    ) -> None:
        """``finger_from_sensor`` and ``camera`` replace the scene's nominal camera mount
        and intrinsics (an as-built rig's camera, ``sim.emulated_rig``)."""
        if side not in SIDE_INDEX:
            raise ValueError(f"`side` must be 'left' or 'right', got {side!r}")
        self.scene = scene
        self.side = side
        self.effects = camera_effects(scene.resolved_effects)
        self.friction = "wrench" in scene.resolved_effects
        self.calls: Counter[str] = Counter()
        self.camera = camera if camera is not None else scene.camera.intrinsics()
        self.geometry = scene.gripper_geometry()
        self.model = scene.object_model()
        self.field = CulledField(self.model.field)
        self.bounds = self.field.bounds
        self.need_normals = "ir" in self.effects
        bubble = self.geometry.bubble
        f_from_s = (
            self.geometry.finger_from_sensor()
            if finger_from_sensor is None
            else np.asarray(finger_from_sensor, np.float64)
        )
        self.finger_from_sensor = f_from_s
        self._r_fs = f_from_s[:3, :3]
        self._o_f = f_from_s[:3, 3]

        # Full resolution: rays, rest range, distance to the plate, rest incidence.
        unit = self.camera.unit_rays()
        self.unit_z = unit[..., 2].astype(np.float32)
        self.dirs_f = unit @ self._r_fs.T
        self.rest_range = bubble.intersect_rays(self._o_f, self.dirs_f)
        self.plate_range = _plate_range(self._o_f, self.dirs_f)
        self.cos_rest = _rest_cos(bubble, self._o_f, self.dirs_f, self.rest_range)
        self.unit = unit
        # float32 working copies: images are float32, and half the bytes is most of
        # the time in these per-pixel passes.
        f32 = np.float32
        self._rest32 = self.rest_range.astype(f32)
        self._max_indent32 = (self.rest_range - self.plate_range).astype(f32)
        self._unit32 = unit.astype(f32)
        self._dir_y32 = np.ascontiguousarray(self.dirs_f[..., 1], dtype=f32)
        self._dir_z32 = np.ascontiguousarray(self.dirs_f[..., 2], dtype=f32)
        self._illum32 = (scene.membrane.ir_gain * self.unit_z**2).astype(f32)

        # The grid the object field is evaluated on (every k-th pixel, centre-aligned
        # with cv2.resize's linear upsampling).
        k = scene.membrane.resolution_divisor
        h, w = self.camera.shape
        self.low_shape = (h // k, w // k)
        hl, wl = self.low_shape
        cols = (np.arange(wl) + 0.5) * (w / wl) - 0.5
        rows = (np.arange(hl) + 0.5) * (h / hl) - 0.5
        x, y = np.meshgrid(
            (cols - self.camera.cx_px) / self.camera.fx_px,
            (rows - self.camera.cy_px) / self.camera.fy_px,
        )
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        unit_lr = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        dirs_lr_f = unit_lr @ self._r_fs.T
        rest_lr = bubble.intersect_rays(self._o_f, dirs_lr_f)
        self._lr_valid = np.flatnonzero(np.isfinite(rest_lr))
        self._lr_unit = unit_lr.reshape(-1, 3)[self._lr_valid]
        self._lr_rest = rest_lr.ravel()[self._lr_valid]
        self._lr_plate = _plate_range(self._o_f, dirs_lr_f).ravel()[self._lr_valid]
        self._lr_rest_points = self._lr_rest[:, None] * self._lr_unit
        self._lr_cos_rest = _rest_cos(bubble, self._o_f, dirs_lr_f, rest_lr).ravel()
        self.tension = Tension.of(scene.bubble)
        # A low-resolution pixel's size on the rest membrane (the tent's steps).
        self._lr_pitch = np.where(np.isfinite(rest_lr), rest_lr * k / self.camera.fx_px, np.inf)

        self._mesh_views: dict[float, Any] = {}
        self._membrane_cache: tuple[tuple[bytes, float], dict[str, np.ndarray]] | None = None
        self.membrane_cache_hits = 0
        self._texture: np.ndarray | None = None
        self._sheet_mm: tuple[float, float] = (0.0, 0.0)

    # ------------------------------------------------------------------ effects

    def render(self, snap: WorldSnapshot) -> BubbleFrame:
        """Run the scene's camera effects for this bubble at ``snap``."""
        frame: dict[str, Any] = {}
        for name in self.effects:
            _STEPS[name](self, frame, snap)
            self.calls[name] += 1
            missing = [a for a in EFFECTS[name].adds if a not in frame]
            if missing:
                raise RuntimeError(f"effect {name!r} did not add {missing}")
        return BubbleFrame(self.side, frame, self.tool_from_sensor(snap.width_m))

    def tool_from_sensor(self, width_m: float) -> np.ndarray:
        return self.geometry.tool_from_finger(self.side, width_m) @ self.finger_from_sensor

    def _membrane(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        if snap.membranes_f is not None:
            frame.update(self._mesh_membrane(snap))
            return
        # The membrane is a pure function of the object's pose and the opening: a held,
        # unmoving object (most of a grasp) reuses the last frame's result.
        key = (np.asarray(snap.tool_from_object, np.float64).tobytes(), float(snap.width_m))
        if self._membrane_cache is not None and self._membrane_cache[0] == key:
            frame.update(self._membrane_cache[1])
            self.membrane_cache_hits += 1
            return
        object_from_sensor = invert(snap.tool_from_object) @ self.tool_from_sensor(snap.width_m)
        rot, trans = object_from_sensor[:3, :3], object_from_sensor[:3, 3]
        hl, wl = self.low_shape
        indent_lr = np.zeros(hl * wl, np.float32)
        cos_lr = self._lr_cos_rest.copy() if self.need_normals else None
        pts = self._lr_rest_points @ rot.T + trans
        near = np.flatnonzero(cull_to_bounds(pts, self.bounds[0], self.bounds[1], 1e-4))
        if near.size:
            phi, grad = self.field.value_and_grad(pts[near])
            inside = phi < 0
            idx = near[inside]
            if idx.size:
                dirs = self._lr_unit[idx] @ rot.T
                origins = np.broadcast_to(trans, dirs.shape)
                t, grad = march_to_surface(
                    self.field,
                    origins,
                    dirs,
                    t_rest=self._lr_rest[idx],
                    phi_rest=phi[inside],
                    grad_rest=grad[inside],
                    t_min=self._lr_plate[idx],
                    steps=self.scene.membrane.march_steps,
                )
                pix = self._lr_valid[idx]
                indent_lr[pix] = self._lr_rest[idx] - t
                if cos_lr is not None:
                    norm = np.linalg.norm(grad, axis=1)
                    flat = np.flatnonzero(norm <= 1e-9)
                    if flat.size:
                        # A point exactly on the surface can get a zero gradient from
                        # the field's slab combination: ask 20 um inside instead.
                        inner = origins[flat] + (t[flat] + 2e-5)[:, None] * dirs[flat]
                        grad[flat] = self.field.value_and_grad(inner)[1]
                        norm[flat] = np.linalg.norm(grad[flat], axis=1)
                    # A zero gradient that remains (a point left far outside by a clamped
                    # step) keeps the rest membrane's incidence.
                    ok = norm > 1e-9
                    cos = np.abs(np.einsum("ij,ij->i", grad, dirs)) / np.where(ok, norm, 1.0)
                    cos_lr[pix[ok]] = cos[ok]
        h, w = self.camera.shape
        indent = touch = indent_lr.reshape(hl, wl)
        if self.tension is not None:
            indent = self.tension.spread(touch, self._lr_pitch)
        if (hl, wl) != (h, w):
            indent = cv2.resize(indent, (w, h), interpolation=cv2.INTER_LINEAR)
            if self.tension is not None:
                touch = cv2.resize(touch, (w, h), interpolation=cv2.INTER_LINEAR)
        indent = np.minimum(indent, self._max_indent32)
        if self.tension is None:
            touch = indent
        frame["indentation_m"] = indent
        frame["range_m"] = self._rest32 - indent
        frame["contact"] = touch > 1e-4  # the object's patch, not the tent around it
        if cos_lr is not None:
            cos_up = cos_lr.reshape(hl, wl).astype(np.float32)
            if (hl, wl) != (h, w):
                cos_up = cv2.resize(cos_up, (w, h), interpolation=cv2.INTER_LINEAR)
            frame["cos_incidence"] = np.where(frame["contact"], cos_up, self.cos_rest)
        result = {
            k: frame[k]
            for k in ("indentation_m", "range_m", "contact", "cos_incidence")
            if k in frame
        }
        for array in result.values():
            array.setflags(write=False)
        self._membrane_cache = (key, result)

    def _mesh_membrane(self, snap: WorldSnapshot) -> dict[str, np.ndarray]:
        """A world's simulated membrane mesh, ray-cast (``sim.mujoco.render``): its dots
        are the latex's own material points, so it adds ``material_shift_m`` too."""
        from sim.mujoco.mesh import contact_tolerance_m, membrane_mesh
        from sim.mujoco.render import MeshView

        assert snap.membranes_f is not None
        spacing = float(snap.membrane_spacing_m)
        view = self._mesh_views.get(spacing)
        if view is None:
            view = MeshView(
                membrane_mesh(self.geometry.bubble, spacing),
                self.unit,
                fx_px=self.camera.fx_px,
                fy_px=self.camera.fy_px,
                cx_px=self.camera.cx_px,
                cy_px=self.camera.cy_px,
                finger_from_sensor=self.geometry.finger_from_sensor(),
                rest_range_m=self.rest_range,
            )
            self._mesh_views[spacing] = view
        surface = np.asarray(snap.membranes_f[self.side], np.float64)
        object_from_finger = invert(snap.tool_from_object) @ self.geometry.tool_from_finger(
            self.side, snap.width_m
        )
        local = surface @ object_from_finger[:3, :3].T + object_from_finger[:3, 3]
        touching = self.field.value(local) < contact_tolerance_m(spacing)
        return view.render(surface, touching)

    def _depth(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        frame["depth_m"] = frame["range_m"] * self.unit_z

    def _ir(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        r = frame["range_m"]
        # Active illumination from the camera: Lambertian return falling with range
        # squared, and an emitter profile dimming towards the image corners.
        frame["amplitude"] = frame["cos_incidence"] * self._illum32 / (r * r)

    def _shear(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        if snap.membranes_f is not None:
            return  # the mesh's material points already carry the latex's motion
        h, w = self.camera.shape
        anchor = snap.anchors.get(self.side)
        contact = frame["contact"]
        if anchor is None or not contact.any():
            frame["material_shift_m"] = np.zeros((h, w, 2), np.float32)
            return
        sigma = self.scene.bubble.shear_blur_px
        weight = contact.astype(np.float32)
        if sigma > 0:
            # Material beyond the patch is dragged along by the membrane's stretch,
            # fading over ~sigma pixels; inside the patch it sticks to the object. The
            # blur runs at a quarter of the resolution: the fade is smooth anyway.
            small = cv2.resize(weight, (w // 4, h // 4), interpolation=cv2.INTER_AREA)
            small = cv2.GaussianBlur(small, (0, 0), sigma / 4.0)
            blurred = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
            # The blur is about 1/2 at the patch's edge: doubling it gives a weight that
            # is 1 in the patch and falls continuously outside (no tear at the edge).
            weight = np.minimum(2.0 * np.maximum(blurred, 0.5 * weight), 1.0)
        # The stick shift of sim.membrane.material_shift is affine in the point for a
        # rigid motion: shift = (I - R_b) p - t_b with back = anchor * inv(now). Fold the
        # sensor-to-tool and tool-to-finger rotations in, keep F's (y, z): one 2x3 map
        # per frame instead of per-pixel transforms.
        back = anchor @ invert(snap.tool_from_object)
        tool_from_sensor = self.tool_from_sensor(snap.width_m)
        finger_from_tool = self.geometry.tool_from_finger(self.side, snap.width_m)[:3, :3].T
        i_minus = np.eye(3) - back[:3, :3]
        lin = (finger_from_tool @ i_minus @ tool_from_sensor[:3, :3])[1:]
        off = (finger_from_tool @ (i_minus @ tool_from_sensor[:3, 3] - back[:3, 3]))[1:]
        r = np.nan_to_num(frame["range_m"], nan=0.0)
        shift = r[..., None] * (self._unit32 @ lin.T.astype(np.float32)) + off.astype(np.float32)
        norm = np.sqrt(shift[..., 0] ** 2 + shift[..., 1] ** 2)
        limit: float | np.ndarray = self.scene.bubble.max_shear_m
        if self.friction:
            # Each point's friction limit (sim.friction): smaller towards the patch's edge.
            indent = frame["indentation_m"]
            g = stiffening(np.where(contact, indent, 0.0), self.scene.bubble.edge_stiffening)
            pressure = snap.pressure_pa.get(self.side, 0.0)
            limit = slip_shift_m(pressure, np.where(contact, g, 1.0), self.scene.bubble)
        scale = np.minimum(1.0, limit / np.maximum(norm, 1e-12))
        frame["material_shift_m"] = shift * (scale * weight)[..., None].astype(np.float32)

    def _dot_pattern(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        texture, (sheet_w, sheet_h) = self.texture()
        res = self.scene.pattern.texture_mm_per_px
        r = frame["range_m"]
        y = np.float32(self._o_f[1]) + r * self._dir_y32
        z = np.float32(self._o_f[2]) + r * self._dir_z32
        shift = frame.get("material_shift_m")
        if shift is not None:
            y = y - shift[..., 0]
            z = z - shift[..., 1]
        map_x = y * np.float32(1000.0 / res) + np.float32(sheet_w / 2 / res - 0.5)
        map_y = z * np.float32(1000.0 / res) + np.float32(sheet_h / 2 / res - 0.5)
        map_x[~np.isfinite(map_x)] = -10.0
        map_y[~np.isfinite(map_y)] = -10.0
        albedo = cv2.remap(
            texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0
        )
        frame["albedo"] = albedo
        frame["amplitude"] = frame["amplitude"] * albedo

    def _tof_noise(self, frame: dict[str, Any], snap: WorldSnapshot) -> None:
        noise = self.scene.noise
        cam = self.scene.camera
        rng = np.random.default_rng([self.scene.seed, SIDE_INDEX[self.side], snap.frame_index])
        r = frame["range_m"]
        amp = frame["amplitude"]
        h, w = r.shape
        # Range noise: ~1% of range at the reference amplitude (docs/facts.md), growing as
        # the return weakens (shot-noise limited: sigma ~ 1 / sqrt(amplitude)).
        sigma = (
            noise.range_sigma_fraction
            * r
            * np.sqrt(noise.reference_amplitude / np.maximum(amp, 1.0))
        )
        noisy = r + sigma * rng.standard_normal((h, w), dtype=np.float32)
        with np.errstate(invalid="ignore"):
            invalid = ~np.isfinite(r) | (noisy < cam.min_range_m) | (noisy > cam.max_range_m)
            invalid |= frame["cos_incidence"] < math.cos(math.radians(noise.grazing_limit_deg))
            invalid |= amp < noise.min_amplitude
            invalid |= sigma > noise.max_noise_m
        frame["depth_m"] = np.where(invalid, np.nan, noisy * self.unit_z).astype(np.float32)
        std = np.sqrt(np.maximum(amp, 0.0) + noise.ir_read_noise**2)
        frame["amplitude"] = (amp + std * rng.standard_normal((h, w), dtype=np.float32)).astype(
            np.float32
        )
        frame["invalid"] = invalid
        frame["noise_m"] = sigma.astype(np.float32)  # the range noise's sigma, per pixel

    def texture(self) -> tuple[np.ndarray, tuple[float, float]]:
        """The printed sheet's albedo raster (built on first use) and its size in mm."""
        if self._texture is None:
            fy, fz = self.geometry.bubble.footprint_semi_axes_m()
            p = self.scene.pattern
            sheet_w = round(2 * fy * 1000 + 4.0)
            sheet_h = round(2 * fz * 1000 + 4.0)
            # Imported here, not at the top: ``sim`` imports this module, and a
            # ``sim.pattern`` already imported makes ``python -m sim.pattern`` warn.
            from sim import pattern as dot_pattern

            tex = dot_pattern.texture(
                density_per_mm2=p.density_per_mm2,
                min_diameter_mm=p.min_diameter_mm,
                max_diameter_mm=p.max_diameter_mm,
                randomness=p.randomness,
                seed=p.seed,
                width_mm=float(sheet_w),
                height_mm=float(sheet_h),
                mm_per_px=p.texture_mm_per_px,
                dot_albedo=p.dot_albedo,
            )
            self._texture = np.ascontiguousarray(tex)
            self._sheet_mm = (float(sheet_w), float(sheet_h))
        return self._texture, self._sheet_mm


_STEPS: dict[str, Callable[[BubbleRenderer, dict[str, Any], WorldSnapshot], None]] = {
    "membrane": BubbleRenderer._membrane,
    "depth": BubbleRenderer._depth,
    "ir": BubbleRenderer._ir,
    "shear": BubbleRenderer._shear,
    "dot_pattern": BubbleRenderer._dot_pattern,
    "tof_noise": BubbleRenderer._tof_noise,
}


def _plate_range(origin_f: np.ndarray, dirs_f: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin_f[0] / dirs_f[..., 0]
    return np.where(dirs_f[..., 0] > 0, t, np.nan)


def _rest_cos(
    bubble: Any, origin_f: np.ndarray, dirs_f: np.ndarray, rest: np.ndarray
) -> np.ndarray:
    pts = origin_f + rest[..., None] * dirs_f
    grad = (pts + [bubble.center_offset_m, 0.0, 0.0]) / bubble.semi_axes_m**2
    grad /= np.linalg.norm(grad, axis=-1, keepdims=True)
    return np.abs(np.sum(grad * dirs_f, axis=-1)).astype(np.float32)


@functools.lru_cache(maxsize=16)
def renderer(scene: Scene, side: str) -> BubbleRenderer:
    """A cached renderer for a scene and side (construction precomputes ~tens of ms)."""
    return BubbleRenderer(scene, side)
