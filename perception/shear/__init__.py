"""Shear of a Soft-bubble membrane from its IR dot pattern (paper, "Shear deformation estimation").

The paper compares two IR images of the printed pseudorandom dot pattern: a reference
taken once the grasp is stable and the latest frame. Dense optical flow (Farneback)
gives a displacement per pixel; their sum, normalized, is the shear direction.

This package does that, and what the paper leaves as future work:

- the flow is Farneback (its parameters are knobs, see :class:`FarnebackParams`) or DIS
  (:class:`DisParams`), optionally on half-resolution input and warm-started from the
  previous frame's flow;
- only pixels of the membrane count: a mask drops the image border (where flow is
  biased), pixels whose depth is invalid (NaN) or outside loose bounds, and IR pixels
  that are dark (invalid) or saturated, in the reference or the current frame;
- ``shear_px`` is the paper's sum divided by the number of masked pixels, i.e. the mean
  displacement in pixels, so that thresholds do not depend on the image size or the
  mask; ``sum_px`` keeps the paper's sum;
- the direction is ``shear_px / |shear_px|`` only when ``|shear_px|`` reaches
  ``min_magnitude_px``; below it, ``direction`` is ``(0, 0)`` and ``direction_defined``
  is ``False`` (never NaN, never an arbitrary unit vector);
- with the depth channel, every tracked dot is back-projected before and after, and its
  3D displacement is projected onto a tangent plane to give ``shear_m``: the plane
  fitted to the reference membrane, or a given basis such as the tool's y and z axes
  (:func:`tool_basis`, what the node uses);
- the torsion (rotation about the contact normal) is the least-squares rotation of the
  displacement field about its centroid, ``sin(theta) = sum(r x d) / sum(|r|^2)``. For
  an affine field ``d = t + A r`` over a region with isotropic second moments this is
  half the field's curl ``(A21 - A12) / 2``, and for a rigid rotation by ``theta`` it
  is exactly ``sin(theta)``; the least-squares form needs no derivatives of the noisy
  flow or depth (a finite-difference curl is available as :func:`flow_curl`).

Conventions: image axes ``x`` right (columns) and ``y`` down (rows); flow ``(dx, dy)``
in pixels maps a reference pixel to where its dot is now. The fitted tangent basis is
``t1`` = the sensor's x axis projected onto the tangent plane, ``n`` = the plane normal
pointing away from the camera, ``t2 = n x t1``; for a camera looking straight at the
membrane this is the image's x and y. A given basis is any right-handed ``t1, t2, n``.
Positive torsion is a right-handed rotation about ``n`` (without depth: about the
optical axis, in the image from +x towards +y). All values are means over the visible
membrane: the part outside the contact does not move, so they are smaller than the
object's own shift and twist. Depth is z-depth in metres along the optical
axis, NaN where invalid (docs/design.md).

Modules: :mod:`~perception.shear.params` (the knobs), :mod:`~perception.shear.flow`
(mask, stretch, dense flow, summary), :mod:`~perception.shear.membrane` (flow to
tangential metres), :mod:`~perception.shear.tracker` (one bubble against its reference;
:class:`GraspShear`, when references are taken), :mod:`~perception.shear.overlay`.
"""

from __future__ import annotations

from geometry.planar import rotation_about_centroid
from perception.shear.flow import (
    DenseFlow,
    flow_curl,
    membrane_mask,
    resize_for_flow,
    scaled_camera,
    stretch_ir,
    summarize_flow,
)
from perception.shear.membrane import MembraneGeometry, tangent_basis, tool_basis
from perception.shear.overlay import draw_overlay
from perception.shear.params import (
    DIS_PRESETS,
    FLOW_METHODS,
    DisParams,
    FarnebackParams,
    ShearParams,
)
from perception.shear.tracker import GraspShear, ShearResult, ShearTracker

__all__ = [
    "DIS_PRESETS",
    "FLOW_METHODS",
    "DenseFlow",
    "DisParams",
    "FarnebackParams",
    "GraspShear",
    "MembraneGeometry",
    "ShearParams",
    "ShearResult",
    "ShearTracker",
    "draw_overlay",
    "flow_curl",
    "membrane_mask",
    "resize_for_flow",
    "rotation_about_centroid",
    "scaled_camera",
    "stretch_ir",
    "summarize_flow",
    "tangent_basis",
    "tool_basis",
]
