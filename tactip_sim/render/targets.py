"""Checkerboard calibration targets seen by the bare lens (no window, no gel).

The target is a flat quad whose emitted radiance is Mitsuba's procedural ``checkerboard``
texture (exact edges, no texture filtering), placed in front of the lens in the camera frame
(x right, y down, z along the optical axis). Only the quad's vertices change between poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..llvm import import_mitsuba
from ..optics.lens import Lens
from ..optics.refraction import Layers
from . import sensor as _sensor
from .noise import FULL_SCALE_RADIANCE
from .renderer import VARIANT


@dataclass(frozen=True)
class Board:
    """A checkerboard of ``squares`` (nx, ny) squares of ``square_mm``; its inner corners
    ((nx - 1) x (ny - 1)) are what OpenCV detects."""

    squares: tuple[int, int] = (8, 6)
    square_mm: float = 3.0

    @property
    def size_mm(self) -> np.ndarray:
        return np.array(self.squares, float) * self.square_mm

    @property
    def inner(self) -> tuple[int, int]:
        return self.squares[0] - 1, self.squares[1] - 1

    def corners_mm(self) -> np.ndarray:
        """((nx-1)(ny-1), 3) inner corners in board coordinates (z = 0), row by row."""
        nx, ny = self.inner
        j, i = np.mgrid[1:ny + 1, 1:nx + 1]
        return np.column_stack([i.ravel() * self.square_mm, j.ravel() * self.square_mm,
                                np.zeros(i.size)])


class TargetRenderer:
    """Render a checkerboard in given poses through the lens alone.

    Parameters
    ----------
    lens : the lens (its resolution and principal point)
    board : the target
    spp : samples per pixel
    """

    def __init__(self, lens: Lens, board: Board | None = None, *, spp: int = 16) -> None:
        self.lens = lens
        self.board = Board() if board is None else board
        self.spp = spp
        self.mi = import_mitsuba(VARIANT)
        _sensor.register(self.mi)
        mi = self.mi
        w, h = lens.resolution
        cfg = _sensor.SensorConfig(
            lens=lens, centre_mm=np.zeros(3), rotation=np.eye(3), refraction="none",
            layers=Layers(), opening_mm=np.ones(2), cavity_mm=np.ones(2), crop_offset=(0, 0),
            crop_size=(w, h))
        nx, ny = self.board.squares
        white, black = 0.8 * FULL_SCALE_RADIANCE, 0.05 * FULL_SCALE_RADIANCE
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "diffuse",
                                      "reflectance": {"type": "rgb", "value": [0.0] * 3}})
        props["emitter"] = mi.load_dict({"type": "area", "radiance": {
            "type": "checkerboard", "color0": {"type": "rgb", "value": [white] * 3},
            "color1": {"type": "rgb", "value": [black] * 3},
            "to_uv": mi.ScalarTransform4f().scale([nx / 2, ny / 2, 1.0])}})
        quad = mi.Mesh("board", 4, 2, props, has_vertex_texcoords=True)
        params = mi.traverse(quad)
        params["vertex_texcoords"] = mi.Float([0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
        params["faces"] = mi.UInt([0, 1, 2, 0, 2, 3])
        params["vertex_positions"] = mi.Float(np.zeros(12, np.float32))
        params.update()
        self.scene = mi.load_dict({"type": "scene", "sensor": _sensor.sensor_dict(cfg, spp),
                                   "integrator": {"type": "path", "max_depth": 1},
                                   "board": quad})
        self.params = mi.traverse(self.scene)

    def corners_camera(self, rotation: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
        """(n, 3) inner corners in the camera frame for a board pose (``R p + t``)."""
        return self.board.corners_mm() @ np.asarray(rotation).T + translation_mm

    def render(self, rotation: np.ndarray, translation_mm: np.ndarray, *, seed: int = 0
               ) -> np.ndarray:
        """(H, W) float32 radiance of the board at pose ``p_cam = R p_board + t``."""
        bw, bh = self.board.size_mm
        quad = np.array([[0, 0, 0], [bw, 0, 0], [bw, bh, 0], [0, bh, 0]], float)
        v = quad @ np.asarray(rotation).T + translation_mm
        normal = np.cross(v[1] - v[0], v[2] - v[0])
        faces = [0, 1, 2, 0, 2, 3]
        if normal @ v.mean(axis=0) > 0:  # emit towards the lens
            faces = [0, 2, 1, 0, 3, 2]
        mi: Any = self.mi
        self.params["board.vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
        self.params["board.faces"] = mi.UInt(faces)
        self.params.update()
        img = np.array(mi.render(self.scene, spp=self.spp, seed=seed), dtype=np.float32)
        return img[..., 0]
