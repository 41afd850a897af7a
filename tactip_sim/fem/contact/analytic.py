"""Closed-form contact answers the solver is validated against."""

from __future__ import annotations

import numpy as np


def hertz_force_mN(e_kpa: float, nu: float, radius_mm: float, depth_mm: float) -> float:
    """Hertz: rigid sphere of radius R on an elastic half-space, indented by d.

    ``F = 4/3 · E/(1 − ν²) · √R · d^1.5``; kPa·mm² = mN.
    """
    return 4.0 / 3.0 * e_kpa / (1.0 - nu**2) * np.sqrt(radius_mm) * depth_mm**1.5


def layer_factor(nu: float, radius_mm: float, depth_mm: float, thickness_mm: float = 20.0
                 ) -> float:
    """F / F_Hertz for a layer of ``thickness_mm`` bonded to a rigid base, to second order in
    ``chi = a / h`` with ``a = sqrt(R d)`` (Dimitriadis et al., Biophys. J. 82, 2002)::

        1 - 2 alpha0 chi / pi + 4 alpha0^2 chi^2 / pi^2,
        alpha0 = -(1.2876 - 1.4678 nu + 1.3442 nu^2) / (1 - nu)
    """
    chi = np.sqrt(radius_mm * depth_mm) / thickness_mm
    a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu**2) / (1.0 - nu)
    return 1.0 - 2.0 * a0 * chi / np.pi + 4.0 * a0**2 * chi**2 / np.pi**2


def sphere_contact(e_kpa: float, nu: float, radius_mm: float, depth_mm: float
                   ) -> tuple[float, float]:
    """Force (mN) and contact radius (mm) of a rigid *sphere* (not Hertz's paraboloid) on an
    elastic half-space, linear elasticity (Segedin, Mathematika 4, 1957)::

        d = a/2 · ln((R + a) / (R − a)),
        F = E*/2 · ((a² + R²) · ln((R + a) / (R − a)) − 2 a R),   E* = E / (1 − ν²)

    It tends to Hertz for a ≪ R (at a / R = 0.67 Hertz's force at the same depth is 5.6 %
    higher). The contact radius is found from the depth by bisection.
    """
    if not 0 < depth_mm < radius_mm:
        raise ValueError(f"depth_mm={depth_mm!r} is out of range: allowed (0, {radius_mm:g})")
    lo, hi = 0.0, radius_mm * (1.0 - 1e-15)
    for _ in range(200):
        a = 0.5 * (lo + hi)
        if a / 2.0 * np.log((radius_mm + a) / (radius_mm - a)) < depth_mm:
            lo = a
        else:
            hi = a
    a = 0.5 * (lo + hi)
    log_term = np.log((radius_mm + a) / (radius_mm - a))
    force = e_kpa / (1.0 - nu**2) / 2.0 * ((a * a + radius_mm**2) * log_term - 2.0 * a * radius_mm)
    return float(force), float(a)
