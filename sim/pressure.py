"""Bubble pressure from the displaced volume: ideal gas at constant temperature.

The air in a bubble (the cap between membrane and plate plus a dead volume in the tube
and fitting) is an ideal gas held at constant temperature (grasps last seconds; the
latex and acrylic are good heat sinks), so ``p V = p0 V0``. The object displaces
``dV`` of it; the free membrane stretches and gives back ``C (p - p0)`` with ``C`` the
membrane compliance (m^3/Pa). Hence ``p (V0 - dV + C (p - p0)) = p0 V0``, a quadratic
in ``p`` with one positive root, which rises monotonically with ``dV``.
"""

from __future__ import annotations

import math


def gauge_pressure_pa(
    displaced_volume_m3: float,
    *,
    rest_volume_m3: float,
    inflation_pa: float,
    ambient_pa: float,
    compliance_m3_per_pa: float,
) -> float:
    """Gauge pressure (over ambient) of a bubble with ``displaced_volume_m3`` pushed in.

    Args:
        displaced_volume_m3: volume the object occupies inside the rest membrane (>= 0).
        rest_volume_m3: air volume at rest (cap plus dead volume).
        inflation_pa: gauge pressure at rest.
        ambient_pa: absolute ambient pressure.
        compliance_m3_per_pa: volume the free membrane gains per pascal.
    """
    p0 = ambient_pa + inflation_pa
    v0 = rest_volume_m3
    dv = min(max(displaced_volume_m3, 0.0), 0.999 * v0)
    c = compliance_m3_per_pa
    if c <= 0.0:
        return p0 * v0 / (v0 - dv) - ambient_pa
    # c p^2 + b p - p0 v0 = 0, with b = v0 - dv - c p0; the positive root, written
    # so that neither sign of b cancels digits.
    b = v0 - dv - c * p0
    disc = math.sqrt(b * b + 4.0 * c * p0 * v0)
    p = 2.0 * p0 * v0 / (b + disc) if b >= 0 else (disc - b) / (2.0 * c)
    return p - ambient_pa
