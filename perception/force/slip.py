"""Slip of one bubble's contact: onset at the patch's edge, then the whole patch, and speed.

Two observations, both from what the bubble measures (docs/force.md):

* **The edge lags the core.** While the patch sticks, its dots move with the object, the
  edge as the core. The edge is stiffer (the stretched free membrane pulls on it) and
  reaches its friction limit first: from then on its dots stop following while the
  core's go on. Over the last ``window`` frames, the edge's displacement along the
  core's, divided by the core's (``edge_follow``), drops from its stick value.
* **The load nears the friction cone.** The tangential force over the normal force,
  divided by the rig's friction coefficient (``use``; from the wrench estimate and the
  calibration), rises towards 1; the whole patch slips at 1 (``patch_use`` is lower:
  the estimate reads large shifts short).

``state`` is ``stick``, ``edge`` (incipient: the edge slips, the core holds) or
``patch`` (the whole patch slides). Onsets are reported once per episode; an episode
ends when ``use`` falls back under ``release_use`` for ``settle_frames``. Everything is
relative to the stable-grasp reference (:meth:`SlipDetector.reference`).

Slip speed: once the whole patch slides its dots stop (the membrane stays at its
limit) while the object moves on, so the dots cannot give the speed. It is the speed of
the patch's centroid (the object's imprint in the depth image) relative to its dots:
zero along a direction the imprint does not change (a cylinder sliding along its own
axis), which is what the bubble cannot see.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

from perception.force.features import ContactFeatures

SlipPhase = Literal["stick", "edge", "patch"]


@dataclass(frozen=True, kw_only=True)
class SlipParams:
    """Thresholds of the slip detector (``use``: tangential / (friction * normal)).

    Attributes:
        edge_use: ``use`` from which the patch's edge counts as slipping.
        patch_use: ``use`` from which the whole patch counts as slipping.
        edge_follow: an edge following the core by less than this (over ``window``
            frames) slips.
        min_core_shift_m: the core must move at least this over ``window`` frames for
            the edge's lag to mean anything (noise otherwise).
        edge_min_use: ... and the load must fill at least this share of the cone (the
            edge cannot slip under a light load; a patch that grows or settles moves
            its edge for other reasons).
        squeeze_change: a change of the normal force by more than this fraction within
            ``window`` frames (the grip was raised or eased) restarts the window: the
            patch changes shape, which is no slip.
        window: frames over which the edge's lag is measured.
        release_use: an episode ends when ``use`` falls under this ...
        settle_frames: ... for this many frames.
        min_normal_n: under this normal force there is no grip to slip from.
    """

    edge_use: float = 0.65
    patch_use: float = 0.8
    edge_follow: float = 0.5
    min_core_shift_m: float = 0.00025
    edge_min_use: float = 0.5
    squeeze_change: float = 0.15
    window: int = 4
    release_use: float = 0.6
    settle_frames: int = 5
    min_normal_n: float = 0.3

    def __post_init__(self) -> None:
        if not 0 < self.release_use <= self.edge_use <= self.patch_use:
            raise ValueError(
                "`release_use`, `edge_use`, `patch_use` must satisfy 0 < release <= edge"
                f" <= patch, got {self.release_use}, {self.edge_use}, {self.patch_use}"
            )
        if self.window < 2:
            raise ValueError(f"`window` must be >= 2, got {self.window!r}")
        if self.settle_frames < 1:
            raise ValueError(f"`settle_frames` must be >= 1, got {self.settle_frames!r}")


@dataclass(frozen=True)
class SlipReport:
    """One bubble's slip at one frame.

    ``onset`` is ``edge`` or ``patch`` on the frame that phase began (else ``""``);
    ``use`` the load's share of the friction cone; ``edge_follow`` how much of the
    core's recent motion the edge followed (1 when the core did not move enough to say);
    ``speed_m_per_s`` the slip speed (0 unless the whole patch slides).
    """

    phase: SlipPhase
    onset: str
    use: float
    edge_follow: float
    speed_m_per_s: float


class SlipDetector:
    """One bubble's slip detector (see the module docstring)."""

    def __init__(self, params: SlipParams | None = None, friction: float = 0.8) -> None:
        self.params = params or SlipParams()
        self.friction = friction
        self.phase: SlipPhase = "stick"
        self._history: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray, float]] = deque(
            maxlen=self.params.window + 1
        )
        self._calm = 0
        self._referenced = False

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
        phase: SlipPhase = "stick"
        if use >= p.patch_use:
            phase = "patch"
        elif use >= p.edge_use or (follow < p.edge_follow and use >= p.edge_min_use):
            phase = "edge"
        onset = ""
        if phase == "stick" and self.phase != "stick":
            # Hold the episode until the load has settled back inside the cone.
            self._calm = self._calm + 1 if use < p.release_use else 0
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
        return SlipReport(phase, onset, use, follow, speed)

    def _edge_follow(self) -> float:
        if len(self._history) < 2:
            return 1.0
        _, core0, edge0, _, _ = self._history[0]
        _, core1, edge1, _, _ = self._history[-1]
        dcore, dedge = core1 - core0, edge1 - edge0
        moved = float(np.hypot(*dcore))
        if moved < self.params.min_core_shift_m:
            return 1.0
        return float(dedge @ dcore) / (moved * moved)

    def _speed(self) -> float:
        if len(self._history) < 2:
            return 0.0
        t0, core0, _, c0, _ = self._history[0]
        t1, core1, _, c1, _ = self._history[-1]
        if t1 <= t0:
            return 0.0
        return float(np.hypot(*((c1 - c0) - (core1 - core0)))) / (t1 - t0)
