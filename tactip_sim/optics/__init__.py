"""Optics: fisheye lens models, refraction through the window and gel, the :class:`Camera`
(lens + mount + window layers, with the exact projection of points and marker caps), marker
visibility, and the numbers behind the lens and mount validation (``tactip validate-lens``).

Everything here is NumPy; Mitsuba is only loaded by :mod:`tactip_sim.render`.
"""

from .camera import REFRACTION_MODES, Camera, Sightlines, cap_outline, project
from .lens import Lens
from .refraction import Layers, bend_up, fresnel_transmittance, refracted_air_directions
from .visibility import Criteria, Visibility, check_view, resolvable, visibility

__all__ = [
    "REFRACTION_MODES",
    "Camera",
    "Criteria",
    "Layers",
    "Lens",
    "Sightlines",
    "Visibility",
    "bend_up",
    "cap_outline",
    "check_view",
    "fresnel_transmittance",
    "project",
    "refracted_air_directions",
    "resolvable",
    "visibility",
]
