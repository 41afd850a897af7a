"""Refraction through the flat window layers: air -> acrylic -> gel.

Sensor frame (mm): the acrylic window fills ``-T <= z <= 0``, the gel lies above ``z = 0``, the
camera sits in air below ``z = -T``. Every interface is a plane of constant z, so a ray keeps
its azimuth and Snell's law conserves the "optical sine" ``s = n sin(angle to +z)`` through all
layers. A camera ray leaving the lens with unit direction ``d`` has ``s = n_air * |d_xy|``.

Forward (:func:`bend_up`): a camera ray is bent at ``z = -T`` and ``z = 0`` and restarted in
the gel; this is what the Mitsuba sensor does per sample (it receives a Dr.Jit namespace as
``xp``). Inverse (:func:`solve_sine`): the ray from the lens centre ``C`` that reaches a point
``P`` satisfies the 1-D equation::

    sum_i h_i s / sqrt(n_i^2 - s^2) = rho

with ``h_i`` the vertical distance travelled in layer ``i`` and ``rho = |P_xy - C_xy|``; its
left side is increasing and convex in ``s``, so Newton's method started to the right of the
root (the air-only solution) converges monotonically.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..scene import Scene
from .lens import NUMPY


@dataclass(frozen=True)
class Layers:
    """The flat optical stack between the camera and the gel.

    window_bottom_mm : z of the window's inner (camera-side) face, ``-thickness``
    n_window, n_gel, n_air : refractive indices
    """

    window_bottom_mm: float = -2.0
    n_window: float = 1.49
    n_gel: float = 1.41
    n_air: float = 1.0

    @classmethod
    def from_scene(cls, scene: Scene) -> Layers:
        return cls(-scene.window.thickness_mm, scene.window.refractive_index,
                   scene.gel.refractive_index)

    @property
    def thickness_mm(self) -> float:
        return -self.window_bottom_mm

    @property
    def critical_angle_gel_rad(self) -> float:
        """Largest angle off the window normal at which the gel can be seen from air (rad)."""
        return float(np.arcsin(min(self.n_air / self.n_gel, 1.0)))


def fresnel_transmittance(cos_i: Any, n1: float, n2: float, xp: Any = NUMPY) -> Any:
    """Unpolarised Fresnel power transmittance from index ``n1`` into ``n2``.

    Parameters
    ----------
    cos_i : (...) float array, cosine of the angle of incidence (>= 0)
    n1, n2 : refractive indices of the incident and transmitted sides
    xp : array namespace

    Returns
    -------
    (...) float array in [0, 1] (0 under total internal reflection)
    """
    eta = n1 / n2
    sin2_t = eta * eta * xp.maximum(1.0 - cos_i * cos_i, 0.0)
    cos_t = xp.sqrt(xp.maximum(1.0 - sin2_t, 0.0))
    rs = (n1 * cos_i - n2 * cos_t) / xp.maximum(n1 * cos_i + n2 * cos_t, 1e-12)
    rp = (n2 * cos_i - n1 * cos_t) / xp.maximum(n2 * cos_i + n1 * cos_t, 1e-12)
    t = 1.0 - 0.5 * (rs * rs + rp * rp)
    return xp.select(sin2_t < 1.0, t, 0.0 * t)


def bend_up(origin: tuple[Any, Any, Any], direction: tuple[Any, Any, Any], layers: Layers,
            xp: Any = NUMPY) -> dict[str, Any]:
    """Bend upward camera rays at ``z = -T`` (air -> acrylic) and ``z = 0`` (acrylic -> gel).

    Parameters
    ----------
    origin : 3-tuple of (...) arrays, ray origins in air below the window (mm, sensor frame)
    direction : 3-tuple of (...) arrays, unit directions; only rays with ``dz > 0`` are valid
    layers : the optical stack
    xp : array namespace (NumPy or Dr.Jit)

    Returns
    -------
    dict with 3-tuples ``window_entry`` (point on ``z = -T``), ``gel_entry`` (point on
    ``z = 0``), ``gel_direction`` (unit) and the arrays ``transmittance`` (product of the two
    Fresnel transmittances times ``(n_air / n_gel)^2``, the radiance scaling from the gel into
    air) and ``upward`` (bool, ``dz > 0``).
    """
    ox, oy, oz = origin
    dx, dy, dz = direction
    upward = dz > 1e-9
    dz_safe = xp.select(upward, dz, 1.0)
    t1 = (layers.window_bottom_mm - oz) / dz_safe
    wx, wy = ox + t1 * dx, oy + t1 * dy
    # acrylic: horizontal components scale by n_air / n_window
    ea = layers.n_air / layers.n_window
    ax, ay = dx * ea, dy * ea
    az = xp.sqrt(xp.maximum(1.0 - ax * ax - ay * ay, 1e-12))
    t2 = layers.thickness_mm / az
    gx, gy = wx + t2 * ax, wy + t2 * ay
    eg = layers.n_air / layers.n_gel
    ex, ey = dx * eg, dy * eg
    ez = xp.sqrt(xp.maximum(1.0 - ex * ex - ey * ey, 1e-12))
    trans = (fresnel_transmittance(dz_safe, layers.n_air, layers.n_window, xp)
             * fresnel_transmittance(az, layers.n_window, layers.n_gel, xp)
             * (layers.n_air / layers.n_gel) ** 2)
    return {
        "window_entry": (wx, wy, 0.0 * wx + layers.window_bottom_mm),
        "gel_entry": (gx, gy, 0.0 * gx),
        "gel_direction": (ex, ey, ez),
        "transmittance": trans,
        "upward": upward,
    }


def solve_sine(rho_mm: np.ndarray, heights_mm: np.ndarray, indices: np.ndarray,
               *, tol: float = 1e-13, max_iter: int = 60) -> np.ndarray:
    """Solve ``sum_i h_i s / sqrt(n_i^2 - s^2) = rho`` for the optical sine ``s``.

    Parameters
    ----------
    rho_mm : (n,) float, horizontal distance from the lens centre to each point (mm)
    heights_mm : (n, k) float, vertical distance travelled in each layer (mm, >= 0); the
        first layer is the one the lens sits in and must have a positive height
    indices : (k,) float, refractive index of each layer (the smallest bounds ``s``)

    Returns
    -------
    (n,) float, ``s`` in ``[0, min(indices))``

    Each point takes Newton steps until its own step is within ``tol`` (compiled:
    :func:`~tactip_sim.optics.refraction_kernels.newton_sine`).
    """
    from .refraction_kernels import newton_sine  # compiled on first use (Numba)

    rho = np.ascontiguousarray(rho_mm, dtype=float)
    h = np.ascontiguousarray(heights_mm, dtype=float)
    n = np.asarray(indices, dtype=float)
    # air-only solution: to the right of the root because the other terms are >= 0
    s = n[0] * rho / np.hypot(rho, h[:, 0])
    s_max = n.min() * (1.0 - 1e-15)
    return newton_sine(rho, h, n * n, np.ascontiguousarray(s, dtype=float), float(s_max),
                       float(tol), int(max_iter))


def layer_heights(points_mm: np.ndarray, centre_mm: np.ndarray, layers: Layers) -> np.ndarray:
    """(n, 3) vertical distances travelled in air, acrylic and gel from the lens centre
    (in air, below the window) up to each point (mm)."""
    z = np.asarray(points_mm, dtype=float)[:, 2]
    zc = float(centre_mm[2])
    zb = layers.window_bottom_mm
    air = np.clip(z, None, zb) - zc
    acrylic = np.clip(z, zb, 0.0) - zb
    gel = np.clip(z, 0.0, None)
    return np.stack([air, acrylic, gel], axis=1)


def refracted_air_directions(points_mm: np.ndarray, centre_mm: np.ndarray, layers: Layers
                             ) -> np.ndarray:
    """Unit directions (sensor frame) in which rays must leave the lens centre to reach
    ``points_mm`` through the window layers.

    Parameters
    ----------
    points_mm : (n, 3) float, sensor frame, above the lens centre
    centre_mm : (3,) float, lens centre (in air, below the window)
    layers : the optical stack

    Returns
    -------
    (n, 3) float, unit vectors

    One compiled pass over the points (:func:`~.refraction_kernels.air_directions`).
    """
    from .refraction_kernels import air_directions  # compiled on first use (Numba)

    p = np.ascontiguousarray(points_mm, dtype=float).reshape(-1, 3)
    c = np.ascontiguousarray(centre_mm, dtype=float)
    return air_directions(p, c, float(layers.window_bottom_mm),
                          np.array([layers.n_air, layers.n_window, layers.n_gel]), 1e-13, 60)


def _refracted_air_directions_numpy(points_mm: np.ndarray, centre_mm: np.ndarray,
                                    layers: Layers) -> np.ndarray:
    """:func:`refracted_air_directions` in NumPy array passes (the tests' reference: the
    compiled loop takes the same steps point by point)."""
    p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    c = np.asarray(centre_mm, dtype=float)
    delta = p[:, :2] - c[:2]
    rho = np.hypot(delta[:, 0], delta[:, 1])
    heights = layer_heights(p, c, layers)
    s = solve_sine(rho, heights, np.array([layers.n_air, layers.n_window, layers.n_gel]))
    safe = np.where(rho > 0, rho, 1.0)
    sin_air = s / layers.n_air
    hx = np.where(rho > 0, delta[:, 0] / safe, 0.0)
    hy = np.where(rho > 0, delta[:, 1] / safe, 0.0)
    return np.stack([sin_air * hx, sin_air * hy, np.sqrt(1.0 - sin_air**2)], axis=1)
