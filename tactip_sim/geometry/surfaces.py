"""Analytic pad shapes and their watertight triangulations.

The dome pad (sensor frame, mm): an elliptical footprint with semi-axes ``a`` (x, distal) and
``b`` (y), a vertical wall from the window (z = 0) up to ``h_w``, and a half-ellipsoidal dome of
height ``d`` on top::

    z(x, y) = h_w + d * sqrt(1 - rho^2),   rho^2 = (x / a)^2 + (y / b)^2 <= 1

The skin/gel interface is the same shape shrunk by the skin thickness ``t``: semi-axes
``a - t``, ``b - t``, dome height ``d - t``, same wall height. Both are closed solids including
their base on the window plane, so their volumes are analytic:
``V = pi a b (h_w + 2 d / 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class DomeShape:
    """A wall-plus-half-ellipsoid solid standing on z = 0 (all lengths mm)."""

    a: float  # semi-axis along x
    b: float  # semi-axis along y
    wall: float  # height of the vertical wall
    dome: float  # height of the dome above the wall

    @property
    def height(self) -> float:
        return self.wall + self.dome

    @property
    def volume(self) -> float:
        """Exact volume (mm³)."""
        return float(np.pi * self.a * self.b * (self.wall + 2.0 * self.dome / 3.0))

    def shrink(self, t: float) -> DomeShape:
        """The interface ``t`` inside this shape (wall height kept)."""
        return DomeShape(self.a - t, self.b - t, self.wall, self.dome - t)

    def rho2(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (np.asarray(x) / self.a) ** 2 + (np.asarray(y) / self.b) ** 2

    def top_z(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Height of the top surface above (x, y); NaN outside the footprint."""
        r2 = self.rho2(x, y)
        with np.errstate(invalid="ignore"):
            return np.where(r2 <= 1.0, self.wall + self.dome * np.sqrt(1.0 - r2), np.nan)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points (n, 3) inside the solid (boundary counts as inside)."""
        p = np.asarray(points, dtype=float)
        r2 = self.rho2(p[:, 0], p[:, 1])
        zt = self.wall + self.dome * np.sqrt(np.clip(1.0 - r2, 0.0, None))
        return (r2 <= 1.0) & (p[:, 2] >= 0.0) & (p[:, 2] <= zt)

    def outward_normal(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) unit outward normals of the dome part at points on it."""
        p = np.asarray(points, dtype=float)
        g = np.stack(
            [p[:, 0] / self.a**2, p[:, 1] / self.b**2, (p[:, 2] - self.wall) / self.dome**2],
            axis=1,
        )
        return g / np.linalg.norm(g, axis=1, keepdims=True)

    def meridian_arc(self, phi: np.ndarray, n_alpha: int = 2048) -> tuple[np.ndarray, np.ndarray]:
        """Arc length along the dome from the apex, in the vertical plane at azimuth ``phi``.

        Returns ``alpha`` (n_alpha,) in [0, pi/2] (the dome's elevation parameter:
        horizontal offset ``R(phi) sin(alpha)``, height ``wall + dome cos(alpha)``) and the
        cumulative arc length (len(phi), n_alpha) mm, by the trapezoidal rule.
        """
        phi = np.atleast_1d(np.asarray(phi, dtype=float))
        r = self.radius_at(phi)[:, None]
        alpha = np.linspace(0.0, np.pi / 2, n_alpha)
        speed = np.sqrt((r * np.cos(alpha)) ** 2 + (self.dome * np.sin(alpha)) ** 2)
        dalpha = alpha[1] - alpha[0]
        arc = np.concatenate(
            [np.zeros((len(phi), 1)), np.cumsum(0.5 * (speed[:, 1:] + speed[:, :-1]), 1) * dalpha],
            axis=1,
        )
        return alpha, arc

    def radius_at(self, phi: np.ndarray) -> np.ndarray:
        """Footprint radius (mm) in direction ``phi`` (rad, from +x)."""
        phi = np.asarray(phi, dtype=float)
        return 1.0 / np.sqrt((np.cos(phi) / self.a) ** 2 + (np.sin(phi) / self.b) ** 2)

    def triangulate(self, resolution: int) -> trimesh.Trimesh:
        """A watertight, outward-oriented triangulation.

        ``resolution`` sets the dome's rings; segments around are ``2 * resolution``.
        """
        n_seg = 2 * resolution
        phi = np.linspace(0.0, 2 * np.pi, n_seg, endpoint=False)
        cphi, sphi = np.cos(phi), np.sin(phi)
        rings: list[np.ndarray] = []
        # dome rings from just below the apex to the junction with the wall
        for alpha in np.linspace(0.0, np.pi / 2, resolution + 1)[1:]:
            s = np.sin(alpha)
            z = self.wall + self.dome * np.cos(alpha)
            rings.append(np.stack([self.a * s * cphi, self.b * s * sphi, np.full(n_seg, z)], 1))
        # wall rings
        n_wall = max(1, int(np.ceil(self.wall / max(self.dome, 1e-9) * resolution / 2)))
        for z in np.linspace(self.wall, 0.0, n_wall + 1)[1:] if self.wall > 0 else []:
            rings.append(np.stack([self.a * cphi, self.b * sphi, np.full(n_seg, z)], 1))
        # base rings towards the centre (z = 0)
        n_base = max(2, resolution // 2)
        for s in np.linspace(1.0, 0.0, n_base + 1)[1:-1]:
            rings.append(np.stack([self.a * s * cphi, self.b * s * sphi, np.zeros(n_seg)], 1))
        apex = np.array([[0.0, 0.0, self.height]])
        base = np.array([[0.0, 0.0, 0.0]])
        return _loft(apex, rings, base)


def _loft(top: np.ndarray, rings: list[np.ndarray], bottom: np.ndarray) -> trimesh.Trimesh:
    """Close a stack of rings (same segment count, ordered top to bottom, counter-clockwise seen
    from +z) with a fan at each pole; faces oriented outward."""
    n = rings[0].shape[0]
    verts = np.concatenate([top, *rings, bottom])
    j = np.arange(n)
    jn = (j + 1) % n
    faces = [np.stack([np.zeros(n, int), 1 + j, 1 + jn], 1)]
    for k in range(len(rings) - 1):
        u, w = 1 + k * n, 1 + (k + 1) * n
        faces.append(np.stack([u + j, w + j, w + jn], 1))
        faces.append(np.stack([u + j, w + jn, u + jn], 1))
    last = 1 + (len(rings) - 1) * n
    pole = len(verts) - 1
    faces.append(np.stack([np.full(n, pole), last + jn, last + j], 1))
    mesh = trimesh.Trimesh(verts, np.concatenate(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def block_mesh(length: float, width: float, height: float) -> trimesh.Trimesh:
    """A box standing on z = 0, centred on the z axis."""
    box = trimesh.creation.box(extents=(length, width, height))
    box.apply_translation((0.0, 0.0, height / 2))
    return box
