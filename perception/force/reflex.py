"""A grip that reacts: raise the grip force on slip, bounded per object; pull or slip.

:class:`GripReflex` answers each slip onset with a firmer grip: enough for the load the
wrench estimate reports to sit ``margin`` inside the friction cone (both bubbles share
it), at least ``step`` times the present force, never above ``max_force_n`` (the
object's bound: a wine glass breaks where a bottle does not), and not again within
``cooldown_secs`` (the jaws need a few frames to squeeze).

:class:`PullWatch` tells a person's pull from a load that grows under gravity (a glass
being filled): the bubbles' force on the object changes, from its baseline, by at
least ``release_force_n`` and not along ``-gravity`` (the bubbles hold up a heavier
object by pushing it up; they resist a pull by pushing against it). The baseline is the
stable grasp's load, following slow drifts over about ``baseline_frames`` estimates
while no pull builds (a pull is fast; a slow one is missed). A pull straight down reads
as a heavier object: what the force cannot tell apart.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta


class ReflexParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The reflex's knobs (newtons, seconds)."""

    max_force_n: Annotated[
        float,
        Meta(
            gt=0,
            le=80.0,
            description="the object's bound on the grip force (WSG 50: 80 N at most).",
        ),
    ] = 40.0
    step: Annotated[
        float,
        Meta(ge=1.0, description="each raise is at least this factor of the present grip force."),
    ] = 1.5
    margin: Annotated[
        float,
        Meta(
            ge=1.0,
            description=(
                "the new grip keeps the load this far inside the friction cone "
                "(tangential / (friction * normal) = 1 / margin)."
            ),
        ),
    ] = 1.6
    cooldown_secs: Annotated[
        float, Meta(ge=0.0, description="no second raise within this time of the last.")
    ] = 0.15


class GripReflex:
    """Raises the grip force on slip onsets (see the module docstring)."""

    def __init__(self, params: ReflexParams, force_n: float, friction: float) -> None:
        self.params = params
        self.force_n = min(force_n, params.max_force_n)
        self.friction = friction
        self.raises = 0
        self._last_secs = -math.inf

    def on_slip(self, stamp_secs: float, load_n: float) -> float | None:
        """A slip onset at ``stamp_secs`` under a tangential load of ``load_n`` (on the
        object, both bubbles); the grip force to command now, or None (no change)."""
        p = self.params
        if stamp_secs - self._last_secs < p.cooldown_secs or self.force_n >= p.max_force_n:
            return None
        needed = p.margin * max(load_n, 0.0) / (2.0 * self.friction)
        target = min(max(self.force_n * p.step, needed), p.max_force_n)
        if target <= self.force_n:
            return None
        self.force_n = target
        self.raises += 1
        self._last_secs = stamp_secs
        return target


class PullWatch:
    """A pull, told from a heavier load by its direction (see the module docstring)."""

    def __init__(
        self,
        release_force_n: float,
        confirm_frames: int,
        gravity_in_tool: tuple[float, float, float] = (0.0, -1.0, 0.0),
        max_cos_up: float = 0.8,
        baseline_frames: int = 30,
    ) -> None:
        self.release_force_n = release_force_n
        self.confirm_frames = confirm_frames
        up = -np.asarray(gravity_in_tool, dtype=np.float64)
        norm = float(np.linalg.norm(up))
        self.up = up / norm if norm > 0 else up
        self.max_cos_up = max_cos_up
        self.baseline_frames = max(1, baseline_frames)
        self.reference: np.ndarray | None = None
        self.count = 0
        self.change_n = np.zeros(3)

    def start(self, object_force_n: np.ndarray) -> None:
        """The stable grasp's load: changes are measured from it."""
        self.reference = np.asarray(object_force_n, dtype=np.float64).copy()
        self.count = 0

    def update(self, object_force_n: np.ndarray) -> bool:
        """True once a pull has lasted ``confirm_frames`` estimates."""
        if self.reference is None:
            return False
        change = np.asarray(object_force_n, dtype=np.float64) - self.reference
        change[0] = 0.0  # the squeeze axis: a firmer grip is no pull
        self.change_n = change
        size = float(np.linalg.norm(change))
        pull = size >= self.release_force_n and float(change @ self.up) < self.max_cos_up * size
        self.count = self.count + 1 if pull else 0
        if not pull:
            # Follow slow drifts (the patch settling, the estimate's own drift): a pull
            # is a change within a few frames, not over seconds.
            self.reference = (
                self.reference
                + (np.asarray(object_force_n, dtype=np.float64) - self.reference)
                / self.baseline_frames
            )
        return self.count >= self.confirm_frames
