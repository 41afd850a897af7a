"""Pad geometry: analytic surfaces, pins on the skin, window, LEDs, occluders."""

from .pad import Pad, build_pad, dome_shapes, rot_x, rot_y
from .pins import PinLayout, map_to_dome, place_pins, triangular_lattice
from .surfaces import DomeShape, block_mesh

__all__ = [
    "DomeShape",
    "Pad",
    "PinLayout",
    "block_mesh",
    "build_pad",
    "dome_shapes",
    "map_to_dome",
    "place_pins",
    "rot_x",
    "rot_y",
    "triangular_lattice",
]
