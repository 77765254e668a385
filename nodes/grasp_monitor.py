"""``grasp_monitor``: stable-grasp detection from both bubbles' pressure and the fingers.

Ports:
    inputs: ``left`` (Pressure), ``right`` (Pressure), ``gripper`` (GripperState).
    outputs: ``grasp`` (GraspState): one per gripper sample, and one at every pressure
        sample that changes the state (``event`` = ``"stable"`` or ``"released"``).

The logic (filters, baselines, hysteresis, dwell) is :class:`perception.grasp.GraspMonitor`;
times are the messages' stamps, so a replayed bag gives the same events.
"""

from __future__ import annotations

from messages.base import Header
from messages.types import GraspState, GripperState, Pressure
from perception.grasp import GraspMonitor, GraspParams, GraspStatus
from runtime.node import Node
from runtime.registry import register


@register("grasp_monitor")
class GraspMonitorNode(Node):
    """Publishes the grasp state; the shear tracker, classifier and tasks key off it."""

    Params = GraspParams
    inputs = {"left": Pressure, "right": Pressure, "gripper": GripperState}
    outputs = {"grasp": GraspState}

    def setup(self) -> None:
        self.monitor = GraspMonitor(self.params)

    def on_left(self, msg: Pressure) -> None:
        self._pressure("left", msg)

    def on_right(self, msg: Pressure) -> None:
        self._pressure("right", msg)

    def on_gripper(self, msg: GripperState) -> None:
        status = self.monitor.update_gripper(msg.speed_m_per_s, msg.width_m, msg.header.stamp_nanos)
        self._publish(status)

    def _pressure(self, port: str, msg: Pressure) -> None:
        if msg.sensor and msg.sensor != port:
            self.io.log.warning(
                "%s: Pressure from sensor %r arrived on port %r", self.name, msg.sensor, port
            )
        status = self.monitor.update_pressure(port, msg.pressure_pa, msg.header.stamp_nanos)
        if status.event:
            self._publish(status)

    def _publish(self, status: GraspStatus) -> None:
        if status.event:
            self.io.log.info("%s: grasp %s", self.name, status.event)
        self.io.publish(
            "grasp",
            GraspState(
                header=Header(stamp_nanos=status.stamp_nanos, frame_id="tool"),
                stable=status.stable,
                event=status.event,
                pressure_rise_left_pa=status.pressure_rise_left_pa,
                pressure_rise_right_pa=status.pressure_rise_right_pa,
                finger_speed_m_per_s=status.finger_speed_m_per_s,
            ),
        )
