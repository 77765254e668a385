"""Slip of one bubble's contact: onset at the patch's edge, then the whole patch, and speed.

Two observations, both from what the bubble measures (docs/force.md):

* **The dots near the pressure's limit.** A point of the membrane sticks while its
  tangential traction, the latex's stiffness times its shift, stays under the friction
  coefficient times its normal traction, which is the gauge pressure ``p`` (a thin
  membrane transmits its pressure): it slips past the shift ``friction p / k``. The
  edge, stiffened by the stretched free membrane, gets there first; the deepest point
  last. So the core's tangential shift (the object's displacement on the latex) over
  ``p`` says how near each part of the patch is to slipping, with no force estimate:
  its area, the unseen part and the tangential stiffness of the object's shape do not
  enter. The rig's two limits (the core's shift per pascal at which the edge, then the
  whole patch, begins to slip) come from the calibration (``edge_m_per_pa``,
  ``patch_m_per_pa``); ``strain`` is the core's shift over the edge's limit.
* **The imprint runs ahead of the dots** (the whole patch). While the patch sticks its
  dots move with the object, and so does the object's imprint (the patch's centroid in
  the depth image), along the directions in which its shape changes the depth; once the
  whole patch slides the dots stop at their limit and the imprint runs on. Over the
  last ``window`` frames (each end a mean over ``imprint_frames`` frames, against the
  imprint's jitter): the imprint moved at least ``patch_lead_m`` and that much
  further along its own motion than the core's dots (``imprint_lead_m``), unless it
  moved against the latex's stretch (the core's shift) while the dots carried the
  stretch on: the patch changing shape under a stuck latex. Where the rig's limits
  are known (below), the core's shift past ``patch_strain`` of the whole patch's
  limit is a backstop for a slide the imprint cannot see (a cylinder along its axis,
  a slide slower than the cue needs).
* **The edge lags the core.** Once the edge slips its dots stop following while the
  core's go on: over the last ``window`` frames, the edge's displacement along the
  core's, divided by the core's (``edge_follow``), drops. A confirmation near the edge's
  limit (``edge_min_strain``), not a cue alone (small increments are noisy).

* **The dots leave the patch's rigid motion** (the edge, with ``edge_cue: dots``). The
  stuck part of the patch moves with the object, as one; a point sliding over it lags.
  The share of the patch's dots whose recent motion leaves that rigid motion
  (``ContactFeatures.departing_share``, ``perception.force.slide``) is the share that
  slides, with no stick limit: on a shell whose limit spreads with the object and the
  load's direction (world.mujoco), the edge slips from ``dots_share`` of it.

* **Both** (the default, ``edge_cue: both``): the earlier of the two edge cues, the
  limit's only where the rig's calibration knows it (its edge onsets' spread,
  ``Calibration.slip_edge_spread``, at most ``limit_max_spread``): a limit dates an
  onset as well as it is known. Where it is known, the dots count from
  ``edge_min_strain`` of it (dots departing far below a known limit are the flow's
  error); where it is not, the whole patch's limit is no backstop either.

``state`` is ``stick``, ``edge`` (incipient: the edge slips, the core holds) or
``patch`` (the whole patch slides). Onsets are reported once per episode; an episode
ends when ``strain`` falls back under ``release_strain`` for ``settle_frames`` (a firmer
grip raises ``p``, hence the limit). Everything is relative to the stable-grasp
reference (:meth:`SlipDetector.reference`) and the dots' tare (the jaws just closed).
``use``, the estimated tangential force over ``friction`` times the normal force, is
reported beside (the load's share of the friction cone, for the reflex's log); it does
not decide: the force estimate's error (10-35% of the tangential load, object by
object) is larger than the margin between a firm hold and the edge's slip.

Slip speed: once the whole patch slides its dots stop (the membrane stays at its
limit) while the object moves on, so the dots cannot give the speed. It is the speed of
the patch's centroid (the object's imprint in the depth image) relative to its dots:
zero along a direction the imprint does not change (a cylinder sliding along its own
axis), which is what the bubble cannot see.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
import numpy as np
from msgspec import Meta

from perception.force.estimators import Calibration
from perception.force.features import ContactFeatures, shift_per_pressure

SlipPhase = Literal["stick", "edge", "patch"]


class SlipParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Thresholds of the slip detector.

    ``strain`` is the core's tangential shift over the shift at which the rig's patch
    edge begins to slip at this pressure (``edge_m_per_pa * p``, from the calibration);
    ``use`` the estimated tangential force over ``friction`` times the normal force.

    The limits are medians over the calibration's onsets, which spread by about 1.3%
    on ``world.sim`` (0.88-0.91 um/Pa for the edge over seeds 0-15: its stick model
    dates the edge at one fixed shift per pascal, and the core's dots read it): the
    edge's threshold sits at 0.98 of its limit (an onset's frame is the first past the
    limit, about half a frame's rise, 1%, above it), confirmed from 0.95 by the edge's
    lag behind the core; the whole patch's cue is its imprint running ahead of the
    dots, with the limit as a backstop.
    """

    edge_cue: Annotated[
        Literal["both", "limit", "dots"],
        Meta(
            description=(
                "what tells the edge's slip: ``limit``, the core's shift near the rig's"
                " stick limit (``edge_strain``, ``edge_follow``); ``dots``, the share of"
                " the patch's dots leaving its rigid motion (``dots_share``), which needs"
                " no limit; ``both``, the earlier of the two, the limit's only where the"
                " rig's calibration knows it (its onsets' spread at most"
                " ``limit_max_spread``: world.sim's 3-5%, not world.mujoco's shell's"
                " 16-22%)."
            )
        ),
    ] = "both"
    limit_max_spread: Annotated[
        float,
        Meta(
            ge=0,
            description=(
                "with ``edge_cue: both``, the stick limit is a cue only where the"
                " calibration's edge onsets spread by at most this (standard deviation"
                " over median, ``Calibration.slip_edge_spread``): the core's shift rises"
                " 1.5-3% of the limit a frame under the benches' loads, so a limit known"
                " to 10% dates an onset within 3-7 frames, one known to 20% within 7-13."
            ),
        ),
    ] = 0.1
    dots_share: Annotated[
        float,
        Meta(
            gt=0,
            le=1,
            description=(
                "with ``edge_cue: dots``, the share of the patch's dots off its rigid"
                " motion (``ContactFeatures.departing_share``) from which the edge slips;"
                " the episode ends when it stays under half of it."
            ),
        ),
    ] = 0.25
    edge_strain: Annotated[
        float, Meta(description="``strain`` from which the patch's edge counts as slipping.")
    ] = 0.98
    patch_lead_m: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "the whole patch slides when, over ``window`` frames, the object's imprint"
                " (the patch's centroid) moved at least this much (m) and ran this much"
                " further along its own motion than the core's dots (not against the"
                " core's shift while the dots carry it on by half this)."
            ),
        ),
    ] = 0.0005
    patch_strain: Annotated[
        float,
        Meta(
            gt=0,
            description=(
                "the core's shift over the whole patch's limit (``patch_m_per_pa * p``)"
                " from which the whole patch counts as slipping, whatever the imprint"
                " says (a backstop for a slide the imprint cannot see), where the stick"
                " limit is a cue (``edge_cue``, ``limit_max_spread``)."
            ),
        ),
    ] = 1.1
    edge_follow: Annotated[
        float,
        Meta(
            description=(
                "an edge following the core by less than this (over ``window`` frames) slips ..."
            )
        ),
    ] = 0.5
    edge_min_strain: Annotated[
        float,
        Meta(
            description=(
                "... when ``strain`` is at least this (the edge's lag alone is noise "
                "under a light load; a patch that grows or settles moves its edge for "
                "other reasons; a limit known to 1.3% is not slipped 5% below it)."
            )
        ),
    ] = 0.95
    min_core_shift_m: Annotated[
        float,
        Meta(
            description=(
                "the core must move at least this over ``window`` frames for the edge's"
                " lag to mean anything (noise otherwise)."
            )
        ),
    ] = 0.00025
    squeeze_change: Annotated[
        float,
        Meta(
            description=(
                "a change of the normal force by more than this fraction within "
                "``window`` frames (the grip was raised or eased) restarts the window: "
                "the patch changes shape, which is no slip."
            )
        ),
    ] = 0.15
    window: Annotated[
        int, Meta(ge=2, description="frames over which the edge's lag is measured.")
    ] = 4
    imprint_frames: Annotated[
        int,
        Meta(
            ge=1,
            description=(
                "the imprint's and the dots' positions at each end of the whole patch's"
                " window are means over this many frames (one frame's imprint jitters"
                " by 0.05 mm on world.sim, by up to 0.25 mm on a membrane meshed at 12 mm)."
            ),
        ),
    ] = 2
    release_strain: Annotated[
        float, Meta(description="an episode ends when ``strain`` falls under this ...")
    ] = 0.8
    settle_frames: Annotated[int, Meta(ge=1, description="... for this many frames.")] = 5
    min_normal_n: Annotated[
        float, Meta(description="under this normal force there is no grip to slip from.")
    ] = 0.3
    min_pressure_pa: Annotated[
        float, Meta(description="under this gauge pressure there is no limit to compare with.")
    ] = 100.0

    def __post_init__(self) -> None:
        if not 0 < self.release_strain <= self.edge_strain:
            raise ValueError(
                "`release_strain`, `edge_strain` must satisfy 0 < release <= edge, got"
                f" {self.release_strain}, {self.edge_strain}"
            )


@dataclass(frozen=True)
class SlipReport:
    """One bubble's slip at one frame.

    ``onset`` is ``edge`` or ``patch`` on the frame that phase began (else ``""``);
    ``use`` the load's share of the friction cone; ``edge_follow`` how much of the
    core's recent motion the edge followed (1 when the core did not move enough to say);
    ``speed_m_per_s`` the slip speed (0 unless the whole patch slides);
    ``imprint_lead_m`` how much further the imprint moved than the core's dots over
    the window (the whole patch's cue).
    """

    phase: SlipPhase
    onset: str
    use: float
    edge_follow: float
    speed_m_per_s: float
    imprint_lead_m: float = 0.0


class SlipDetector:
    """One bubble's slip detector (see the module docstring)."""

    def __init__(
        self,
        params: SlipParams | None = None,
        friction: float = 0.8,
        edge_m_per_pa: float = 0.7e-6,
        patch_m_per_pa: float = 0.95e-6,
        edge_spread: float = 0.0,
    ) -> None:
        if not (edge_m_per_pa > 0 and patch_m_per_pa > 0):
            raise ValueError(
                f"slip limits must be > 0, got {edge_m_per_pa!r} and {patch_m_per_pa!r}"
            )
        self.params = params or SlipParams()
        self.friction = friction
        self.edge_m_per_pa = edge_m_per_pa
        self.patch_m_per_pa = patch_m_per_pa
        p = self.params
        # Which cues tell the edge's slip (``SlipParams.edge_cue``); the stick limits
        # (the edge's, the whole patch's backstop) only where ``limit_cue``.
        self.limit_cue = p.edge_cue == "limit" or (
            p.edge_cue == "both" and edge_spread <= p.limit_max_spread
        )
        self.dots_cue = p.edge_cue in ("dots", "both")
        self.phase: SlipPhase = "stick"
        self._history: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray, float]] = deque(
            maxlen=self.params.window + self.params.imprint_frames
        )
        self._calm = 0
        self._referenced = False

    @classmethod
    def for_rig(cls, cal: Calibration, params: SlipParams | None = None) -> SlipDetector:
        """A detector with the rig's friction and slip limits (its calibration)."""
        return cls(
            params,
            cal.friction,
            cal.slip_edge_m_per_pa,
            cal.slip_patch_m_per_pa,
            cal.slip_edge_spread,
        )

    def reference(self) -> None:
        """A stable grasp began: what moved before it is not slip."""
        self._history.clear()
        self.phase = "stick"
        self._calm = 0
        self._referenced = True

    def drop(self) -> None:
        """The grasp ended."""
        self.reference()
        self._referenced = False

    def update(
        self,
        features: ContactFeatures,
        force_n: np.ndarray,
        stamp_secs: float,
    ) -> SlipReport:
        """The slip of this frame, from its features and the bubble's estimated force."""
        p = self.params
        normal = abs(float(force_n @ features.normal_in_tool))
        tangential = float(np.hypot(force_n[1], force_n[2]))
        use = tangential / (self.friction * normal) if normal >= p.min_normal_n else 0.0
        if not (self._referenced and features.in_contact and features.tracked):
            self._history.clear()
            return SlipReport("stick", "", use, 1.0, 0.0)
        if self._history and abs(normal - self._history[0][4]) > p.squeeze_change * normal:
            self._history.clear()
        self._history.append(
            (
                stamp_secs,
                features.core_shift_m,
                features.edge_shift_m,
                features.centroid_in_tool[1:],
                normal,
            )
        )
        follow = self._edge_follow()
        shift_per_pa = shift_per_pressure(features, p.min_pressure_pa)
        strain = shift_per_pa / self.edge_m_per_pa
        lead = self._imprint_lead()
        limit_edge = strain >= p.edge_strain or (
            follow < p.edge_follow and strain >= p.edge_min_strain
        )
        dots_edge = features.departing_share >= p.dots_share
        if self.limit_cue:
            # Where the limit is known no point of the latex slides far below it: the
            # dots departing there are the flow's error (a face seen at grazing angles).
            dots_edge = dots_edge and strain >= p.edge_min_strain
        edge = (self.limit_cue and limit_edge) or (self.dots_cue and dots_edge)
        calm = (not self.limit_cue or strain < p.release_strain) and (
            not self.dots_cue or features.departing_share < 0.5 * p.dots_share
        )
        phase: SlipPhase = "stick"
        if lead >= p.patch_lead_m or (
            self.limit_cue and shift_per_pa >= p.patch_strain * self.patch_m_per_pa
        ):
            phase = "patch"
        elif edge:
            phase = "edge"
        onset = ""
        if phase == "stick" and self.phase != "stick":
            # Hold the episode until the shift (or the dots' departure) has settled.
            self._calm = self._calm + 1 if calm else 0
            phase = self.phase if self._calm < p.settle_frames else "stick"
        else:
            self._calm = 0
        rank = {"stick": 0, "edge": 1, "patch": 2}
        if rank[phase] > rank[self.phase]:
            onset = phase
        elif phase != "stick" and rank[phase] < rank[self.phase]:
            phase = self.phase  # within an episode the phase does not go back
        self.phase = phase
        speed = self._speed() if phase == "patch" else 0.0
        return SlipReport(phase, onset, use, follow, speed, lead)

    def _edge_follow(self) -> float:
        if len(self._history) < 2:
            return 1.0
        _, core0, edge0, _, _ = self._history[max(0, len(self._history) - 1 - self.params.window)]
        _, core1, edge1, _, _ = self._history[-1]
        dcore, dedge = core1 - core0, edge1 - edge0
        moved = float(np.hypot(*dcore))
        if moved < self.params.min_core_shift_m:
            return 1.0
        return float(dedge @ dcore) / (moved * moved)

    def _imprint_lead(self) -> float:
        """How much further the imprint moved than the core's dots over the window,
        along the imprint's own motion (0 while it moved less than ``patch_lead_m``, or
        against the core's shift while the dots carried it on by half that).

        While the patch sticks the dots move with the object; the imprint moves with
        it too, but only along the directions its shape changes the depth (a cylinder's
        imprint does not move along its axis): the dots' motion projected on the
        imprint's equals the imprint's. Once the whole patch slides the dots stop at
        their limit and the imprint runs on.
        """
        if len(self._history) < 2:
            return 0.0
        # Each end of the window: the mean of ``imprint_frames`` frames (fewer while the
        # window fills), so that one frame's jitter of the imprint is no slide.
        k = max(1, min(self.params.imprint_frames, len(self._history) // 2))
        history = list(self._history)
        core0 = np.mean([h[1] for h in history[:k]], axis=0)
        c0 = np.mean([h[3] for h in history[:k]], axis=0)
        core1 = np.mean([h[1] for h in history[-k:]], axis=0)
        c1 = np.mean([h[3] for h in history[-k:]], axis=0)
        moved = c1 - c0
        norm = float(np.hypot(*moved))
        if norm < self.params.patch_lead_m:
            return 0.0
        # An imprint moving against the latex's stretch (the core's shift) while the
        # dots carry the stretch on (by half the cue's lead or more) is the patch
        # changing shape under a stuck latex, not a slide: a mug pulled on
        # world.mujoco's shell, its dots moving on with the object, its imprint
        # drifting 0.5 mm the other way, 20 frames before its latex slid (the dots'
        # motion against the imprint's added to the lead). Once the whole patch slides
        # the dots stop or fall back, and the imprint may run either way (a bottle's
        # taper on the curved membrane: against the stretch).
        stretch = float(np.hypot(*core1))
        carried = float((core1 - core0) @ core1) / stretch if stretch > 0.0 else 0.0
        if float(moved @ core1) < 0.0 and carried >= 0.5 * self.params.patch_lead_m:
            return 0.0
        return norm - float((core1 - core0) @ moved) / norm

    def _speed(self) -> float:
        if len(self._history) < 2:
            return 0.0
        t0, core0, _, c0, _ = self._history[0]
        t1, core1, _, c1, _ = self._history[-1]
        if t1 <= t0:
            return 0.0
        return float(np.hypot(*((c1 - c0) - (core1 - core0)))) / (t1 - t0)
