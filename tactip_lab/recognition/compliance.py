"""A compliant object pressed into the pad: a Hertzian spring in series with the pad.

The FEM treats every indenter as rigid. A soft ball is modelled as the rigid sphere of its
shape carried on a Hertzian spring, the ball's own flattening against a rigid flat (Johnson,
*Contact Mechanics*, 1985, eq. 4.22):

    F_ball(delta_b) = 4/3 · E* · sqrt(R) · delta_b^(3/2),    E* = E / (1 - nu²)

and the robot commands the total approach ``d`` (position control, as a gripper closing to a
width). The pad's indentation ``delta_p`` and the ball's ``delta_b = d - delta_p`` split so
that the forces match, ``F_pad(delta_p) = F_ball(d - delta_p)``, with ``F_pad`` from the FEM
press itself; the root is bracketed on [0, d] (``F_pad(0) = 0 < F_ball(d)``,
``F_pad(d) > 0 = F_ball(0)``) and found by Brent's method.

What this leaves out (documented in docs/recognition.md): the ball's flattening does not
change the shape pressed into the pad (the rigid sphere keeps its radius); the law is the one
for a rigid flat counterface, whereas the pad is curved and itself soft; no friction or
damping. A stiff ball of the same radius is rigid: the pair differ only in the depth split.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

DEPTH_XTOL_MM = 1e-4
"""The depth split is solved to 0.1 µm (far below a pixel's 0.06 mm footprint)."""


def hertz_force_N(delta_mm: float, radius_mm: float, youngs_modulus_kpa: float,
                  poisson_ratio: float) -> float:
    """Force (N) of a Hertzian sphere of ``radius_mm`` flattened by ``delta_mm`` against a
    rigid flat (kPa = 1e-3 N/mm²)."""
    if delta_mm <= 0:
        return 0.0
    e_star = youngs_modulus_kpa * 1e-3 / (1.0 - poisson_ratio**2)  # N/mm²
    return 4.0 / 3.0 * e_star * math.sqrt(radius_mm) * delta_mm**1.5


def split_depth(press: Callable[[float], Any], depth_mm: float, radius_mm: float,
                youngs_modulus_kpa: float, poisson_ratio: float) -> tuple[Any, float]:
    """Press a compliant sphere to the commanded ``depth_mm``.

    Parameters
    ----------
    press : the FEM press of the rigid sphere at a pad depth (mm) -> ContactState (its
        ``force_N`` is used)
    depth_mm : commanded approach beyond first contact (mm, > 0)
    radius_mm, youngs_modulus_kpa, poisson_ratio : the ball

    Returns
    -------
    (state, pad_depth_mm) : the FEM state at the pad's share of the depth (the ball takes
        ``depth_mm - pad_depth_mm``)
    """
    from scipy.optimize import brentq

    if not depth_mm > 0:
        raise ValueError(f"depth_mm={depth_mm!r} is out of range: allowed (0, inf) for a "
                         "compliant object")
    states: dict[float, Any] = {}

    def imbalance(pad_mm: float) -> float:
        states[pad_mm] = s = press(pad_mm)
        return s.force_N - hertz_force_N(depth_mm - pad_mm, radius_mm, youngs_modulus_kpa,
                                         poisson_ratio)

    root = brentq(imbalance, 0.0, depth_mm, xtol=DEPTH_XTOL_MM)
    state = states[root] if root in states else press(root)
    return state, float(root)


__all__ = ["DEPTH_XTOL_MM", "hertz_force_N", "split_depth"]
