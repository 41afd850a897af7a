"""Optics: fisheye lens models, refraction through the window and gel, analytic projection of
markers, their visibility, and the geometry validation behind ``tactip validate-lens``.

Everything here is NumPy; Mitsuba is only loaded by :mod:`tactip_sim.render`.
"""

from .lens import Lens
from .project import REFRACTION_MODES, Sightlines, project, sightlines
from .refraction import Layers, bend_up, fresnel_transmittance, refracted_air_directions
from .visibility import (
    Criteria,
    Visibility,
    cap_images,
    check_view,
    resolvable,
    visibility,
    visible,
)

__all__ = [
    "REFRACTION_MODES",
    "Criteria",
    "Layers",
    "Lens",
    "Sightlines",
    "Visibility",
    "bend_up",
    "cap_images",
    "check_view",
    "fresnel_transmittance",
    "project",
    "refracted_air_directions",
    "resolvable",
    "sightlines",
    "visibility",
    "visible",
]
