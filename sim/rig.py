"""The simulated rig a scene runs on: gripper, bubbles, cameras, dot pattern, noise.

Sections of a scene file (``sim.scene``) that describe the hardware rather than what
happens: the WSG 50's limits and scripted commands (``gripper``), the membranes
(``bubble``), the ToF cameras and their mounts (``camera``), the printed dots
(``pattern``), the sensor noise (``noise``) and the membrane renderer's knobs
(``membrane``). Every default is a docs/facts.md figure; each section checks its own
values and raises ``ValueError`` naming the field (the scene loader adds the file).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from geometry.camera import PinholeCamera
from geometry.gripper import BubbleGeometry

GRIPPER_COMMANDS = ("move", "grasp", "release", "stop", "home")


def positive(obj: Any, *names: str) -> None:
    """Each named attribute of ``obj`` is a finite number > 0 (else ``ValueError``)."""
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"`{name}` must be > 0, got {value!r}")


def nonnegative(obj: Any, *names: str) -> None:
    """Each named attribute of ``obj`` is a finite number >= 0 (else ``ValueError``)."""
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise ValueError(f"`{name}` must be >= 0, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class ScriptedCommand:
    """A gripper command the scene issues at ``t_secs`` (as a supervisor would)."""

    t_secs: float
    command: str
    width_m: float = 0.0
    speed_m_per_s: float = 0.05
    force_n: float = 20.0

    def __post_init__(self) -> None:
        nonnegative(self, "t_secs", "width_m", "force_n")
        positive(self, "speed_m_per_s")
        if self.command not in GRIPPER_COMMANDS:
            raise ValueError(
                f"`command` must be one of {', '.join(GRIPPER_COMMANDS)}, got {self.command!r}"
            )


@dataclass(frozen=True, kw_only=True)
class GripperSpec:
    """WSG 50 emulation: start opening, speed limit, scripted commands (docs/facts.md)."""

    initial_width_m: float = 0.11
    max_width_m: float = 0.11
    max_speed_m_per_s: float = 0.42
    max_force_n: float = 80.0
    plate_outset_m: float = 0.02
    commands: tuple[ScriptedCommand, ...] = ()

    def __post_init__(self) -> None:
        positive(self, "max_width_m", "max_speed_m_per_s", "max_force_n")
        nonnegative(self, "initial_width_m", "plate_outset_m")
        if self.initial_width_m > self.max_width_m:
            raise ValueError(
                f"`initial_width_m` must be <= max_width_m, got {self.initial_width_m!r}"
            )


@dataclass(frozen=True, kw_only=True)
class BubbleSpec:
    """Membrane shape (see ``geometry.gripper``), inflation and mechanics.

    ``compliance_m3_per_pa`` is how much the free membrane's volume grows per pascal
    (latex stretching elsewhere); ``max_shear_m`` is where stick turns to slip.

    The contact's tangential mechanics (``sim.friction``, used by the ``wrench`` and
    ``slip`` effects): ``friction`` is the latex's Coulomb coefficient on the object;
    ``shear_stiffness_n_per_m3`` the tangential traction per metre of material shift
    and per square metre of contact at the patch's centre; ``edge_stiffening`` how
    much stiffer the patch's edge is (the stretched free membrane pulls on it), so the
    edge reaches its friction limit and slips first.

    ``tension_n_per_m``: the latex's in-plane tension in a contact (0, the default: a
    slack membrane pressed by its gauge pressure alone). With tension the free membrane
    leaves the contact's edge as a tent down towards the plate instead of keeping its
    rest shape (a broader, smoother dent around the patch), and pulls on the object
    along that tent, so the jaws stop wider at the same force (``sim.membrane.Tension``).
    The auto-labeller draws it per grasp (``world.autolabel``'s ``tension_n_per_m``).
    """

    semi_axis_normal_m: float = 0.04165
    semi_axis_lateral_m: float = 0.04165
    semi_axis_length_m: float = 0.0625
    cap_height_m: float = 0.025
    inflation_pa: float = 1000.0
    ambient_pa: float = 101_325.0
    dead_volume_m3: float = 10e-6
    compliance_m3_per_pa: float = 5e-9
    max_shear_m: float = 0.006
    shear_blur_px: float = 20.0
    sample_spacing_m: float = 0.003
    friction: float = 0.8
    shear_stiffness_n_per_m3: float = 4.5e5
    edge_stiffening: float = 1.0
    tension_n_per_m: float = 0.0

    def __post_init__(self) -> None:
        positive(self, "ambient_pa", "max_shear_m", "sample_spacing_m")
        nonnegative(self, "tension_n_per_m")
        positive(self, "friction", "shear_stiffness_n_per_m3")
        nonnegative(self, "edge_stiffening")
        nonnegative(self, "inflation_pa", "dead_volume_m3", "compliance_m3_per_pa")
        nonnegative(self, "shear_blur_px")

    def geometry(self) -> BubbleGeometry:
        return BubbleGeometry(
            semi_axis_normal_m=self.semi_axis_normal_m,
            semi_axis_lateral_m=self.semi_axis_lateral_m,
            semi_axis_length_m=self.semi_axis_length_m,
            cap_height_m=self.cap_height_m,
        )


@dataclass(frozen=True, kw_only=True)
class CameraSpec:
    """Internal ToF camera (docs/facts.md: pico flexx class) and its mount on the finger."""

    width_px: int = 224
    height_px: int = 172
    hfov_deg: float = 62.0
    vfov_deg: float = 45.0
    frame_rate_hz: float = 30.0
    min_range_m: float = 0.04
    max_range_m: float = 0.11
    back_m: float = 0.02
    z_m: float = -0.035
    pitch_deg: float = 35.0

    def __post_init__(self) -> None:
        positive(self, "width_px", "height_px", "hfov_deg", "vfov_deg", "frame_rate_hz")
        positive(self, "min_range_m", "max_range_m")
        if self.max_range_m <= self.min_range_m:
            raise ValueError(f"`max_range_m` must be > min_range_m, got {self.max_range_m!r}")

    def intrinsics(self) -> PinholeCamera:
        return PinholeCamera.from_fov(
            self.width_px, self.height_px, hfov_deg=self.hfov_deg, vfov_deg=self.vfov_deg
        )


@dataclass(frozen=True, kw_only=True)
class PatternSpec:
    """The printed dot pattern (paper, Printed Patterning), see ``sim.pattern``."""

    density_per_mm2: float = 0.08
    min_diameter_mm: float = 1.0
    max_diameter_mm: float = 2.0
    randomness: float = 0.8
    seed: int = 0
    dot_albedo: float = 0.25
    texture_mm_per_px: float = 0.1

    def __post_init__(self) -> None:
        positive(self, "density_per_mm2", "min_diameter_mm", "max_diameter_mm")
        positive(self, "texture_mm_per_px")
        if self.max_diameter_mm < self.min_diameter_mm:
            raise ValueError(
                f"`max_diameter_mm` must be >= min_diameter_mm, got {self.max_diameter_mm!r}"
            )
        if not 0.0 <= self.randomness <= 1.0:
            raise ValueError(f"`randomness` must be in [0, 1], got {self.randomness!r}")
        if not 0.0 <= self.dot_albedo <= 1.0:
            raise ValueError(f"`dot_albedo` must be in [0, 1], got {self.dot_albedo!r}")


@dataclass(frozen=True, kw_only=True)
class NoiseSpec:
    """ToF noise and validity (docs/facts.md: ~1% of range; driver invalidity rules)."""

    range_sigma_fraction: float = 0.01
    reference_amplitude: float = 1500.0
    max_noise_m: float = 0.07
    grazing_limit_deg: float = 80.0
    min_amplitude: float = 60.0
    ir_read_noise: float = 8.0

    def __post_init__(self) -> None:
        nonnegative(self, "range_sigma_fraction", "min_amplitude", "ir_read_noise")
        positive(self, "reference_amplitude", "max_noise_m")
        if not 0.0 < self.grazing_limit_deg <= 90.0:
            raise ValueError(
                f"`grazing_limit_deg` must be in (0, 90], got {self.grazing_limit_deg!r}"
            )


@dataclass(frozen=True, kw_only=True)
class MembraneSpec:
    """Rendering knobs of the membrane model (accuracy against time, see bench/sim.py).

    ``resolution_divisor`` evaluates the object field on every k-th pixel and upsamples
    the indentation; ``march_steps`` is the number of Newton steps along each ray from
    the rest membrane to the object's surface (field evaluations: ``march_steps``).
    """

    resolution_divisor: int = 4
    march_steps: int = 3
    ir_gain: float = 5.4

    def __post_init__(self) -> None:
        if self.resolution_divisor not in (1, 2, 4):
            raise ValueError(
                f"`resolution_divisor` must be 1, 2 or 4, got {self.resolution_divisor!r}"
            )
        if not 1 <= self.march_steps <= 8:
            raise ValueError(f"`march_steps` must be in [1, 8], got {self.march_steps!r}")
        positive(self, "ir_gain")
