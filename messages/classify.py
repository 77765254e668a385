"""Messages of the auto-labelling pipeline (tactile classification).

``GraspRequest`` is what the ``supervisor.autolabel`` node asks of the world: put this
object at this pose between the open jaws (after a random drop), then it will close on it
to ``grasp_width_m`` with ``force_n``. A simulated world places the object; on hardware
it is the arm's grasp generator's job. The pose is a 4x4 float64 ``tool_from_object``;
``variant`` names the class's variant (``geometry.variants``), -1 its reference shape.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np

from messages.base import Array, Header, Message


class GraspRequest(Message):
    """One random grasp of the auto-labelling run (see ``perception.classify.autolabel``)."""

    header: Header
    grasp_id: int
    object_name: str
    class_label: str
    tool_from_object: Annotated[np.ndarray, Array("float64", (4, 4))]
    open_width_m: float
    grasp_width_m: float
    force_n: float
    variant: int = -1
