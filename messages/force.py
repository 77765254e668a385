"""Contact forces: what a world knows of them (for scoring and calibration only).

Forces are newtons and torques newton-metres, both in the ``tool`` frame, torques taken
about the tool frame's origin. Arrays of two rows are ``[left, right]`` bubbles.
"""

from __future__ import annotations

from typing import Annotated

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
