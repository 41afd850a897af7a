"""The per-frame "cap layer" integrator (``tactip_caps``).

Only the marker caps (and pins) move between frames; the skin, rim and body do not. So the
renderer draws the static scene once (``direct`` integrator, LEDs) and, per frame, only asks
which moving object each camera ray meets first. This integrator casts the camera ray
(preliminary intersection only: no shading, no shadow rays) and returns the RGB triple
``(L, c, 0)``: ``L`` the radiance of the cap hit (a per-cap table, ``diffused`` shading),
``c = 1`` if a cap or pin was hit. Accumulated by the film with the sensor's weight ``w``
(window transmittance), a pixel holds ``(mean w L, mean w c)``, from which the renderer
composites ``background * (1 - coverage) + L``.

The per-cap radiance table is a Dr.Jit array read through a gather, so new values do not
recompile the kernel.
"""

from __future__ import annotations

from typing import Any

from .handoff import Handoff

PLUGIN = "tactip_caps"
NO_SHAPE = 2**32 - 1
"""A shape index that matches no shape (indices are unsigned 32-bit)."""


class LayerState:
    """Mutable inputs of one cap-layer scene.

    radiance : Dr.Jit Float (n_caps,), radiance of each cap
    n_edge : triangles per cap (the cap index of triangle ``t`` is ``t // n_edge``)
    caps_index, pins_index : positions of the caps and pins meshes in ``scene.shapes()``
        (``NO_SHAPE`` = absent)
    """

    def __init__(self, n_edge: int) -> None:
        self.radiance: Any = None
        self.n_edge = n_edge
        self.caps_index = NO_SHAPE
        self.pins_index = NO_SHAPE


_STATES: Handoff[LayerState] = Handoff()


def add_state(state: LayerState) -> int:
    """Store a layer state; returns its ``state_id`` for the scene dictionary."""
    return _STATES.put(state)


def register(mi: Any) -> None:
    """Register ``tactip_caps`` for Mitsuba's current variant (idempotent)."""
    if mi.variant() in _STATES.registered:
        return
    import drjit as dr

    class CapLayerIntegrator(mi.SamplingIntegrator):
        """First-hit cap radiance and coverage (see the module docstring)."""

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            self.state = _STATES.take(props["state_id"])  # shared with the renderer

        def sample(self, scene, sampler, ray, medium=None, active=True):  # noqa: ARG002
            st = self.state
            pi = scene.ray_intersect_preliminary(ray, True, active)
            valid = pi.is_valid() & active
            on_cap = valid & (pi.shape_index == st.caps_index)
            on_pin = valid & (pi.shape_index == st.pins_index)
            cap = mi.UInt32(pi.prim_index) // st.n_edge
            radiance = dr.gather(mi.Float, st.radiance, cap, on_cap)
            cover = dr.select(on_cap | on_pin, 1.0, 0.0)
            return mi.Color3f(dr.select(on_cap, radiance, 0.0), cover, 0.0), True, []

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return "CapLayerIntegrator[]"

    mi.register_integrator(PLUGIN, lambda props: CapLayerIntegrator(props))
    _STATES.registered.add(mi.variant())
