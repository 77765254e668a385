"""Contact forces: what a world knows of them, and what the bubbles estimate.

``WrenchTruth`` is a world's ground truth (for scoring and calibration only);
``WrenchEstimate``, ``BubbleContact`` and ``SlipState`` are the ``wrench`` and ``slip``
nodes' outputs (docs/force.md).

Forces are newtons and torques newton-metres, both in the ``tool`` frame, torques taken
about the tool frame's origin. Arrays of two rows are ``[left, right]`` bubbles.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np

from messages.base import Array, Header, Message

_PerBubble3 = Annotated[np.ndarray, Array("float64", (2, 3))]
_Vec3 = Annotated[np.ndarray, Array("float64", (3,))]


class WrenchTruth(Message):
    """The true contact wrenches of one world instant (a world's ground truth).

    ``bubble_force_n[i]`` is the force the object exerts on bubble ``i``'s membrane;
    ``object_force_n`` the total contact force on the object (from both bubbles and
    anything else it touches), ``object_torque_nm`` its torque. ``pressure_pa`` is each
    bubble's gauge pressure and ``volume_m3`` its enclosed air volume (0 where the world
    does not model it). ``source`` names the world that computed them (``sim``, ``mujoco``).
    """

    header: Header
    source: str
    bubble_force_n: _PerBubble3
    bubble_torque_nm: _PerBubble3
    object_force_n: _Vec3
    object_torque_nm: _Vec3
    pressure_pa: list[float]
    volume_m3: list[float]


_PerBubble2 = Annotated[np.ndarray, Array("float64", (2,))]
SlipPhase = Literal["stick", "edge", "patch"]
"""``SlipState.phase``: ``stick`` (the patch holds), ``edge`` (its edge slips, the core
holds: incipient slip), ``patch`` (the whole patch slides)."""
SlipOnset = Literal["", "edge", "patch"]


class WrenchEstimate(Message):
    """The contact wrench estimated from the bubbles (``wrench`` node), tool frame.

    Rows of the per-bubble arrays are ``[left, right]``: the force the object exerts on
    that bubble's membrane and its torque about the tool frame's origin; ``object_*`` is
    the bubbles' total on the object (their negated sum). ``*_sigma_*`` are one-sigma
    uncertainties per component (the calibration's residual spread). ``method`` names
    the estimator (``physics``, ``ridge``).
    """

    header: Header
    method: str
    bubble_force_n: _PerBubble3
    bubble_torque_nm: _PerBubble3
    bubble_force_sigma_n: _PerBubble3
    bubble_torque_sigma_nm: _PerBubble3
    object_force_n: _Vec3
    object_torque_nm: _Vec3
    object_force_sigma_n: _Vec3
    object_torque_sigma_nm: _Vec3
    in_contact: list[bool]
    area_m2: list[float]

    finite_fields: ClassVar[tuple[str, ...]] = ("bubble_force_n", "bubble_torque_nm")


class BubbleContact(Message):
    """One bubble's contact as the ``wrench`` node measured it (``perception.force``).

    Areas are projected on the plate; shifts are the dots' mean tangential displacement
    since the tare (the jaws closing on the object), tool (y, z), over the patch, its
    core and its edge; ``force_n`` is the bubble's estimated force (tool frame);
    ``departing_share`` the share of the patch's dots whose recent motion left its rigid
    motion (``perception.force.slide``).
    """

    header: Header
    sensor: str
    in_contact: bool
    tracked: bool
    pressure_pa: float
    pressure_rise_pa: float
    area_m2: float
    volume_m3: float
    centroid_in_tool: _Vec3
    normal_in_tool: _Vec3
    shift_m: _PerBubble2
    core_shift_m: _PerBubble2
    edge_shift_m: _PerBubble2
    torsion_rad: float
    patch_px: int
    force_n: _Vec3
    departing_share: float = 0.0


class SlipState(Message):
    """One bubble's slip (``slip`` node): its phase, the onset (once, on the frame a phase
    begins), the load's share of the friction cone (``use``), how much of the core's
    recent motion the edge followed, and the slip speed (0 unless the patch slides)."""

    header: Header
    sensor: str
    phase: SlipPhase
    onset: SlipOnset = ""
    use: float = 0.0
    edge_follow: float = 1.0
    speed_m_per_s: float = 0.0
