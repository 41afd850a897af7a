"""The pose of a rigid indenter relative to the pad.

Convention (sensor frame: +z out of the pad, +x distal): the indenter's frame is rotated by
``R = R_y(pitch) · R_x(roll) · R_z(yaw)``; its approach axis is ``m = R · e_z`` (the plate's
normal), and the indenter is pushed along ``-m`` into the pad. ``depth_mm`` is the indentation
beyond first contact at that orientation (0 = just touching, < 0 = clear of the pad). The
first-contact point is the outermost point of the undeformed pad surface along ``m``; a lateral
``offset_mm`` (x, y) shifts the indenter's approach line in its own x/y axes (equal to the sensor
x/y at roll = pitch = yaw = 0), after which first contact is found again along ``-m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ANGLE_LIMIT_DEG = 90.0


class PoseError(ValueError):
    """A pose value is not finite, or out of its allowed range (the message names both)."""


def rotation(roll_deg: float, pitch_deg: float, yaw_deg: float = 0.0) -> np.ndarray:
    """``R_y(pitch) · R_x(roll) · R_z(yaw)`` (3, 3): indenter frame -> sensor frame."""
    r, p, y = np.deg2rad([roll_deg, pitch_deg, yaw_deg])
    cr, sr, cp, sp_, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp_], [0.0, 1.0, 0.0], [-sp_, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return ry @ rx @ rz


@dataclass(frozen=True)
class Pose:
    """Where the indenter is.

    roll_deg, pitch_deg : orientation of the approach axis, each in the open interval (-90, 90)
    depth_mm : indentation beyond first contact, mm (negative: no contact)
    offset_mm : (2,) lateral offset of the approach line in the indenter's x/y axes, mm
    yaw_deg : rotation of the indenter about its approach axis, in [-180, 180] (orients a
        cylinder's or edge's axis, or a mesh)
    """

    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    depth_mm: float = 0.0
    offset_mm: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("roll_deg", "pitch_deg", "depth_mm", "yaw_deg"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise PoseError(f"{name}={value!r} must be a number") from None
            if not math.isfinite(value):
                raise PoseError(f"{name}={value!r} must be finite")
            object.__setattr__(self, name, value)
        for name in ("roll_deg", "pitch_deg"):
            value = getattr(self, name)
            if not -ANGLE_LIMIT_DEG < value < ANGLE_LIMIT_DEG:
                raise PoseError(f"{name}={value:g} is out of range: allowed (-90, 90) degrees")
        if not -180.0 <= self.yaw_deg <= 180.0:
            raise PoseError(f"yaw_deg={self.yaw_deg:g} is out of range: allowed [-180, 180]")
        try:
            off = tuple(float(v) for v in self.offset_mm)
        except (TypeError, ValueError):
            raise PoseError(f"offset_mm={self.offset_mm!r} must be two numbers (x, y)") from None
        if len(off) != 2 or not all(math.isfinite(v) for v in off):
            raise PoseError(f"offset_mm={self.offset_mm!r} must be two finite numbers (x, y)")
        object.__setattr__(self, "offset_mm", off)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) indenter frame -> sensor frame."""
        return rotation(self.roll_deg, self.pitch_deg, self.yaw_deg)

    @property
    def approach(self) -> np.ndarray:
        """(3,) unit approach axis ``m`` (the indenter moves along ``-m``)."""
        return self.rotation[:, 2]

    def __str__(self) -> str:
        s = f"Pose(roll={self.roll_deg:g}°, pitch={self.pitch_deg:g}°, depth={self.depth_mm:g} mm"
        if any(self.offset_mm):
            s += f", offset=({self.offset_mm[0]:g}, {self.offset_mm[1]:g}) mm"
        if self.yaw_deg:
            s += f", yaw={self.yaw_deg:g}°"
        return s + ")"
