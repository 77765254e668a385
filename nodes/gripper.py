"""``gripper.sim``: the simulated WSG 50's state report.

Ports:
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``.
    outputs: ``state`` (GripperState): opening, finger speed (magnitude), grip force and
        state (idle | moving | holding | fault), one per world state, with its stamp.

Commands go to ``world.sim``'s ``command`` input, which integrates the jaws (so the
cameras and this report see one motion); a hardware graph replaces this node with the
WSG 50 driver, which takes the commands itself.
"""

from __future__ import annotations

from messages.sim import WorldState
from messages.types import GripperState
from runtime.node import Node
from runtime.registry import register
from sim import gripper_state
from sim.wire import from_message


@register("gripper.sim")
class SimGripper(Node):
    """Reports the simulated jaws (see the module docstring)."""

    inputs = {"world": WorldState}
    outputs = {"state": GripperState}

    def on_world(self, msg: WorldState) -> None:
        self.io.publish("state", gripper_state(from_message(msg), msg.header.stamp_nanos))
