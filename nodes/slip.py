"""``slip``: slip of each bubble's contact, from what the ``wrench`` node measured.

Ports:
    inputs: ``contact`` (messages.force.BubbleContact, from ``wrench/contact``: both
        bubbles), ``grasp`` (GraspState: a stable grasp starts the reference, a release
        ends it).
    outputs: ``slip`` (messages.force.SlipState, one per contact message: ``sensor``
        says which bubble; ``onset`` is ``edge`` or ``patch`` on the frame that phase
        began).

The logic (the dots' shift against the pressure's limit, the edge's lag behind the
core, the dots leaving the patch's rigid motion, or by default the earlier of those,
the limit's only where the calibration knows it; the imprint running ahead of the
dots, the episode's hysteresis) is :class:`perception.force.slip.SlipDetector`; the
friction coefficient, the slip limits and their spread are the rig's, from the same
``calibration`` file the ``wrench`` node reads.
Times are the messages' stamps, so a replayed bag gives the same onsets.
"""

from __future__ import annotations

import msgspec

from geometry.gripper import SIDES
from messages.base import Header
from messages.errors import NodeError
from messages.force import BubbleContact, SlipState
from messages.types import GraspState
from perception.force.estimators import Calibration
from perception.force.features import ContactFeatures
from perception.force.slip import SlipDetector, SlipParams
from runtime.node import Node
from runtime.params import ExistingFile
from runtime.registry import register


class SlipNodeParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The detector's thresholds and the rig's calibration file (its friction)."""

    detector: SlipParams = msgspec.field(default_factory=SlipParams)
    calibration: ExistingFile = "models/force/sim.json"


@register("slip")
class SlipNode(Node):
    """Slip onset and speed per bubble (see the module docstring)."""

    Params = SlipNodeParams
    inputs = {"contact": BubbleContact, "grasp": GraspState}
    outputs = {"slip": SlipState}

    def setup(self) -> None:
        try:
            cal = Calibration.load(self.params.calibration)
        except ValueError as err:
            raise NodeError(f"{self.name}: {err}") from err
        self.detectors = {s: SlipDetector.for_rig(cal, self.params.detector) for s in SIDES}
        self.stable = False

    def on_grasp(self, msg: GraspState) -> None:
        if msg.stable and (not self.stable or msg.event == "stable"):
            for detector in self.detectors.values():
                detector.reference()
        elif not msg.stable and self.stable:
            for detector in self.detectors.values():
                detector.drop()
        self.stable = msg.stable

    def on_contact(self, msg: BubbleContact) -> None:
        detector = self.detectors.get(msg.sensor)
        if detector is None:
            self.io.log.warning("%s: contact from unknown sensor %r", self.name, msg.sensor)
            return
        stamp = msg.header.stamp_nanos
        report = detector.update(features_of(msg), msg.force_n, stamp / 1e9)
        if report.onset:
            self.io.log.info(
                "%s: %s bubble slips (%s; use %.2f)",
                self.name,
                msg.sensor,
                report.onset,
                report.use,
            )
        self.io.publish(
            "slip",
            SlipState(
                header=Header(stamp_nanos=stamp, frame_id="tool"),
                sensor=msg.sensor,
                phase=report.phase,
                onset=report.onset,  # type: ignore[arg-type]
                use=float(report.use),
                edge_follow=float(report.edge_follow),
                speed_m_per_s=float(report.speed_m_per_s),
            ),
        )


def features_of(msg: BubbleContact) -> ContactFeatures:
    """The features a ``BubbleContact`` carries."""
    return ContactFeatures(
        msg.in_contact, msg.tracked, msg.pressure_pa, msg.pressure_rise_pa, msg.area_m2,
        msg.volume_m3, msg.centroid_in_tool, msg.normal_in_tool, msg.shift_m,
        msg.core_shift_m, msg.edge_shift_m, msg.torsion_rad, msg.patch_px, msg.departing_share,
    )  # fmt: skip
