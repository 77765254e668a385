"""Messages of the shear tracker beyond those in ``messages.types``."""

from __future__ import annotations

from typing import Literal

from messages.base import Header, Message


class ShearReset(Message):
    """Ask the shear tracker to retake its reference on the next frame.

    ``sensor`` is ``"left"``, ``"right"`` or ``""`` for both bubbles. While the grasp is
    not stable a reset only drops the reference (none is taken until the grasp is stable).
    """

    header: Header
    sensor: Literal["", "left", "right"] = ""
