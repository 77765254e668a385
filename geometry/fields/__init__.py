"""Proximity fields: the paper's corner-corrected capped cylinder, its siblings, unions.

A proximity field ``phi`` maps a point in the field's frame to a scalar: ``phi >= 0``
outside, ``phi < 0`` inside, ``0`` on the surface (paper, "Proximity Pose
Estimation"). Every field here offers the same three views of one formula:

- ``value(points)``: (N, 3) float64 points to (N,) values, vectorized numpy;
- ``value_and_grad(points)``: values and (N, 3) gradients, analytic, vectorized numpy;
- ``casadi(p)``: the value as a CasADi expression of a 3x1 ``SX``/``MX`` symbol.

The "slab" primitives (cylinder, box, frustum) use the paper's combination of a slab
vector ``delta`` (one signed distance per pair of parallel faces, or per side)::

    phi = || max(delta, 0) ||_2 + vmax(min(delta, 0))

which is the Euclidean distance to the nearest edge or corner outside (the corner
correction) and the distance to the nearest face inside. Sphere and capsule are exact
signed distances.

Finite everywhere, by construction, for values and gradients. The outer norm
``||max(delta, 0)||`` is ``sqrt(0)`` for every point inside the surface (half of a
noisy patch) and its plain derivative there is NaN; an epsilon only inside the radial
norm ``||p_xy||`` does not cure it. So every gradient of a norm is written
``v / max(||v||, 1e-15)`` in numpy (exactly ``v / ||v||`` above 1e-15 m, zero at
``v = 0``), and every CasADi norm is ``if_else(s > EPS2, sqrt(max(s, EPS2)), 0)``, whose
branches are both finite with finite derivatives, so no NaN leaks into a Jacobian or a
Hessian. Values agree between the two to 1e-15 m. On the cylinder axis the radial
gradient is zero (the field is not differentiable there; zero is its minimum-norm
subgradient). Gradients have unit length outside right-angled slabs (Eikonal); at a
frustum's slanted rim they reach ``1/sin`` of the rim angle.

The package: ``base`` (the :class:`Field` interface, the finite norms every field uses,
:func:`casadi_function`), ``slab`` (the slab combination and its primitives: capped
cylinder, box, frustum), ``exact`` (sphere and capsule), ``compose`` (a field moved by a
rigid transform, unions).
"""

from geometry.fields.base import EPS2, Field, casadi_function
from geometry.fields.compose import Transformed, Union
from geometry.fields.exact import Capsule, Sphere
from geometry.fields.slab import Box, CappedCylinder, Frustum, SlabField

__all__ = [
    "EPS2",
    "Box",
    "CappedCylinder",
    "Capsule",
    "Field",
    "Frustum",
    "SlabField",
    "Sphere",
    "Transformed",
    "Union",
    "casadi_function",
]
