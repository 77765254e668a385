"""``pressure.sim``: one bubble's simulated pressure sensor.

Ports:
    inputs: ``world`` (messages.sim.WorldState) from ``world.sim``.
    outputs: ``pressure`` (Pressure): gauge pascals, one per world state, with its
        stamp, when the scene lists ``pressure`` (nothing otherwise).

The pressure itself (ideal gas at constant temperature, ``sim.pressure``) is part of
the world's mechanics, since the grip force follows from it; this node reports it.
"""

from __future__ import annotations

from messages.sim import WorldState
from messages.types import Pressure
from runtime.node import Node
from runtime.registry import register
from sim import pressure
from sim.effects import resolve
from sim.wire import SensorParams, from_message


@register("pressure.sim")
class SimPressure(Node):
    """Publishes the bubble's gauge pressure (see the module docstring)."""

    Params = SensorParams
    inputs = {"world": WorldState}
    outputs = {"pressure": Pressure}

    def setup(self) -> None:
        self.warned = False

    def on_world(self, msg: WorldState) -> None:
        if "pressure" not in resolve(msg.effects):
            if not self.warned:
                self.io.log.info(
                    "%s: the scene has no pressure effect; nothing to publish", self.name
                )
                self.warned = True
            return
        snap = from_message(msg)
        self.io.publish("pressure", pressure(snap, self.params.sensor, msg.header.stamp_nanos))
