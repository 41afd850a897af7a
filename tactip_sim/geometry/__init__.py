"""Pad geometry: analytic surfaces, pins on the skin, window, camera mount, occluders."""

from .pad import CameraMount, Pad, build_pad, camera_mount, dome_shapes, rot_x, rot_y
from .pins import PinLayout, place_pins, triangular_lattice
from .surfaces import DomeShape, block_mesh

__all__ = [
    "CameraMount",
    "DomeShape",
    "Pad",
    "PinLayout",
    "block_mesh",
    "build_pad",
    "camera_mount",
    "dome_shapes",
    "place_pins",
    "rot_x",
    "rot_y",
    "triangular_lattice",
]
