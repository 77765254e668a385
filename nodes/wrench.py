"""``wrench``: the contact wrench of each bubble and of the grasp, from the bubbles alone.

Ports:
    inputs: ``left``, ``right`` (ToFImage: depth and IR; each optional, wire the
        bubbles you have), ``left_pressure``, ``right_pressure`` (Pressure), ``gripper``
        (GripperState).
    outputs: ``wrench`` (messages.force.WrenchEstimate: per bubble and on the object,
        tool frame, N and N m, with one-sigma uncertainties), once per pair of frames
        of one instant (stamps within ``max_skew_secs``: a frame waits for its partner,
        however late; an instant whose other frame was dropped gets no estimate, since
        a pair of two instants is wrong by the load's change between them), or per
        frame with one bubble (from its third frame with none of the other's);
        ``contact`` (messages.force.BubbleContact: what each bubble measured, for the
        ``slip`` node), one per frame.

What each frame is judged by is the gripper's state and the bubble's pressure at the
frame's stamp (``perception.contact.StampedHistory``), so the order in which the inputs
of an instant arrive does not change the estimate. Frames taken with the gripper open
and still (``reference_min_width_m``, ``reference_max_speed_m_per_s``) build the free
bubble's reference; the first frame taken with the gripper ``holding`` tares the dots (the jaws
just closed: zero tangential load); opening the gripper drops the tare. The estimator
(``method``: ``physics`` or ``ridge``) and its constants come from the ``calibration``
file (``python -m bench.force_data`` writes the simulated rig's; docs/force.md).
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec
import numpy as np
from msgspec import Meta

from geometry.camera import PinholeCamera
from geometry.gripper import SIDES
from messages.base import Header
from messages.errors import NodeError
from messages.force import BubbleContact, WrenchEstimate
from messages.types import GripperState, Pressure, ToFImage, pose_is_known
from perception.contact import InstantPairs, StampedHistory
from perception.force.estimators import BubbleWrench, Calibration, estimate
from perception.force.features import BubbleFeatures, ContactFeatures, FeatureParams
from runtime.node import Node
from runtime.params import ExistingFile
from runtime.registry import register

DEFAULT_CALIBRATION = "models/force/sim.json"
PAIR_HISTORY = 8  # results of one bubble kept while waiting for the other's
SINGLE_AFTER_FRAMES = 3  # frames of one bubble with none of the other: a one-bubble graph


class WrenchParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The estimator, its calibration file, the features' knobs, and frame timing."""

    method: Annotated[
        Literal["physics", "ridge"],
        Meta(description="``physics`` (pressure x area, a shear stiffness) or ``ridge``."),
    ] = "physics"
    calibration: Annotated[
        ExistingFile,
        Meta(description="the rig's calibration file (JSON, ``perception.force.estimators``)."),
    ] = DEFAULT_CALIBRATION
    features: Annotated[
        FeatureParams, Meta(description="the contact filter and dot-flow knobs.")
    ] = msgspec.field(default_factory=FeatureParams)
    reference_min_width_m: Annotated[
        float, Meta(ge=0, description="the gripper counts as open from this opening on ...")
    ] = 0.1
    reference_max_speed_m_per_s: Annotated[
        float, Meta(ge=0, description="... and as still below this finger speed.")
    ] = 0.001
    max_skew_secs: Annotated[
        float,
        Meta(ge=0, description="the most two bubbles' frames may differ to make one estimate."),
    ] = 0.011


@register("wrench")
class WrenchNode(Node):
    """Contact wrench per bubble and for the grasp (see the module docstring)."""

    Params = WrenchParams
    inputs = {
        "left": ToFImage,
        "right": ToFImage,
        "left_pressure": Pressure,
        "right_pressure": Pressure,
        "gripper": GripperState,
    }
    optional_inputs = frozenset({"left", "right", "left_pressure", "right_pressure"})
    outputs = {"wrench": WrenchEstimate, "contact": BubbleContact}

    def setup(self) -> None:
        try:
            self.calibration = Calibration.load(self.params.calibration)
        except ValueError as err:
            raise NodeError(f"{self.name}: {err}") from err
        self.extractors = {s: BubbleFeatures(self.params.features) for s in SIDES}
        self.pressure_pa = {s: StampedHistory(0.0, 64) for s in SIDES}
        # The gripper at each stamp: "free" (open and still), "holding", or "" (else).
        self.gripper = StampedHistory("", 64)
        # Each bubble's results waiting for the other's of the same instant.
        self.pairs: InstantPairs[tuple[int, ContactFeatures, BubbleWrench]] = InstantPairs(
            PAIR_HISTORY
        )
        self.frames = dict.fromkeys(SIDES, 0)
        self.warned: set[str] = set()

    def on_left_pressure(self, msg: Pressure) -> None:
        self.pressure_pa["left"].record(msg.header.stamp_nanos, msg.pressure_pa)

    def on_right_pressure(self, msg: Pressure) -> None:
        self.pressure_pa["right"].record(msg.header.stamp_nanos, msg.pressure_pa)

    def on_gripper(self, msg: GripperState) -> None:
        prm = self.params
        if (
            msg.width_m >= prm.reference_min_width_m
            and msg.speed_m_per_s <= prm.reference_max_speed_m_per_s
        ):
            state = "free"
        elif msg.state == "holding":
            state = "holding"
        else:
            state = ""
        if state == "free" and self.gripper.latest != "free":
            for extractor in self.extractors.values():
                extractor.clear()
        self.gripper.record(msg.header.stamp_nanos, state)

    def on_left(self, msg: ToFImage) -> None:
        self._image("left", msg)

    def on_right(self, msg: ToFImage) -> None:
        self._image("right", msg)

    def _image(self, side: str, msg: ToFImage) -> None:
        if msg.ir.size == 0 or msg.depth_m.shape != msg.ir.shape:
            self._warn(side, "frames carry no IR image or no depth of its shape; skipped")
            return
        if not pose_is_known(msg.tool_from_sensor):
            self._warn(side, "frames carry no `tool_from_sensor` (the camera mount); refused")
            return
        extractor = self.extractors[side]
        stamp = msg.header.stamp_nanos
        camera = PinholeCamera.from_frame(msg)
        state = self.gripper.at(stamp)
        pressure_pa = self.pressure_pa[side].at(stamp)
        if state == "free":
            extractor.free_frame(msg.depth_m, pressure_pa)
            extractor.untare()
        elif state == "holding" and not extractor.tared:
            extractor.tare(msg.ir, msg.depth_m, camera, msg.tool_from_sensor)
        features = extractor.update(
            msg.ir, msg.depth_m, pressure_pa, camera, msg.tool_from_sensor, stamp / 1e9
        )
        wrench = estimate(features, side, self.calibration, self.params.method)
        self.io.publish("contact", _contact(side, msg.header, features, wrench))
        self.frames[side] += 1
        self._pair(side, (stamp, features, wrench))

    def _pair(self, side: str, result: tuple[int, ContactFeatures, BubbleWrench]) -> None:
        """Publish the estimate of ``result``'s instant once both bubbles' frames are in."""
        stamp = result[0]
        other = "right" if side == "left" else "left"
        if self.frames[other] == 0 and self.frames[side] >= SINGLE_AFTER_FRAMES:
            self.io.publish("wrench", self._estimate(stamp, {side: result}))
            return
        partner = self.pairs.match(side, stamp, result, self.params.max_skew_secs * 1e9)
        if partner is not None:
            self.io.publish("wrench", self._estimate(stamp, {side: result, other: partner}))

    def _estimate(
        self, stamp: int, pair: dict[str, tuple[int, ContactFeatures, BubbleWrench]]
    ) -> WrenchEstimate:
        zero = (0, ContactFeatures.empty(0.0, np.zeros(3)), BubbleWrench.zero())
        rows = [pair.get(s, zero) for s in SIDES]
        force = np.array([w.force_n for _, _, w in rows])
        torque = np.array([w.torque_nm for _, _, w in rows])
        fsig = np.array([w.force_sigma_n for _, _, w in rows])
        tsig = np.array([w.torque_sigma_nm for _, _, w in rows])
        return WrenchEstimate(
            header=Header(stamp_nanos=stamp, frame_id="tool"),
            method=self.params.method,
            bubble_force_n=force,
            bubble_torque_nm=torque,
            bubble_force_sigma_n=fsig,
            bubble_torque_sigma_nm=tsig,
            object_force_n=-force.sum(axis=0),
            object_torque_nm=-torque.sum(axis=0),
            object_force_sigma_n=np.sqrt((fsig**2).sum(axis=0)),
            object_torque_sigma_nm=np.sqrt((tsig**2).sum(axis=0)),
            in_contact=[bool(f.in_contact) for _, f, _ in rows],
            area_m2=[float(f.area_m2) for _, f, _ in rows],
        )

    def _warn(self, side: str, text: str) -> None:
        if side not in self.warned:
            self.io.log.warning("%s: %s %s", self.name, side, text)
            self.warned.add(side)


def _contact(side: str, header: Header, f: ContactFeatures, w: BubbleWrench) -> BubbleContact:
    return BubbleContact(
        header=Header(stamp_nanos=header.stamp_nanos, frame_id="tool"),
        sensor=side,
        in_contact=bool(f.in_contact),
        tracked=bool(f.tracked),
        pressure_pa=float(f.pressure_pa),
        pressure_rise_pa=float(f.pressure_rise_pa),
        area_m2=float(f.area_m2),
        volume_m3=float(f.volume_m3),
        centroid_in_tool=np.asarray(f.centroid_in_tool, np.float64),
        normal_in_tool=np.asarray(f.normal_in_tool, np.float64),
        shift_m=np.asarray(f.shift_m, np.float64),
        core_shift_m=np.asarray(f.core_shift_m, np.float64),
        edge_shift_m=np.asarray(f.edge_shift_m, np.float64),
        torsion_rad=float(f.torsion_rad),
        patch_px=int(f.patch_px),
        force_n=np.asarray(w.force_n, np.float64),
        departing_share=float(f.departing_share),
    )
