"""A-posteriori estimate of each marker's discretisation error (rod pins).

A rod's tip is its base's mean displacement plus the skin's mean rotation under its base over
the pin's lever (:mod:`~tactip_sim.fem.markers.kinematics`); on the pad's meshes the tips' error is
that rotation's (docs/convergence.md: the roots alone converge first, the rotation over the 3 mm
lever adds the rest). The estimate compares the solution's gradient with a recovered one
(Zienkiewicz–Zhu): the skin's displacement gradient averaged at every mesh vertex over the skin
tets that share it (volume-weighted) and interpolated linearly, a continuous field that is
closer to the exact gradient than the discontinuous finite-element one where the mesh resolves
the field. At the base weight's centroid in each skin element under the pin (weights ``w_k``,
the element's share of the base) the difference's rotation part ``1/2 curl (grad u_h - G*)``
is taken; the estimate is the lever (anchor to tip, :attr:`~.markers.kinematics.Markers.levers_mm`)
times its root mean square over the base:

    eta_i = |lever_i| * sqrt( sum_k w_k |1/2 curl (grad u_h - G*)(x_k)|^2 )

Measured against what local refinement moved (docs/convergence.md, "An estimate per marker"):
it ranks the rim pins that a mesh leaves unconverged, and is of their error's size.
"""

from __future__ import annotations

import numpy as np

from ..discretisation.space import Space, gradient_operator
from .kinematics import Markers

__all__ = ["marker_error_estimate", "recovered_gradient", "stuck_marker_errors"]

# rows (3 c + k = d u_c / d x_k) of the gradient whose differences are the curl's components
_CURL = ((7, 5), (2, 6), (3, 1))


def _vertex_gradients(space: Space, u: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(len(elements), 4, 9) the field's gradient in each element at its four vertices."""
    out = np.empty((len(elements), 4, 9))
    for i in range(4):
        lam = np.zeros((len(elements), 4))
        lam[:, i] = 1.0
        out[:, i] = (gradient_operator(space, elements, lam) @ u).reshape(-1, 9)
    return out


def recovered_gradient(space: Space, u: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(n_vertices, 9) the displacement gradient recovered at the mesh's vertices from the
    ``elements`` (one material's: the gradient jumps across a material interface): each
    element's gradient at the vertex, averaged over the elements that share it, weighted by
    their volumes. Vertices no listed element touches get zeros."""
    from ...mesh.topology import tet_volumes

    nv = space.n_vertices
    vert = space.elements[elements, :4]
    vol = np.abs(tet_volumes(space.nodes[:nv], vert))
    grads = _vertex_gradients(space, u, elements)
    acc = np.zeros((nv, 9))
    weight = np.zeros(nv)
    for i in range(4):
        np.add.at(acc, vert[:, i], vol[:, None] * grads[:, i])
        np.add.at(weight, vert[:, i], vol)
    return acc / np.where(weight > 0, weight, 1.0)[:, None]


def marker_error_estimate(markers: Markers, space: Space, u: np.ndarray,
                          skin_elements: np.ndarray) -> np.ndarray | None:
    """(p,) mm: the estimated discretisation error of each marker from the full nodal field
    ``u`` (n_dofs,); ``skin_elements`` are the elements of the skin the rods are bonded to
    (the gradient is recovered over them). ``None`` for markers without a rod base to
    average over (embedded tips, or rods turned at a single point).

    Raises
    ------
    ValueError
        ``u`` does not hold one value per degree of freedom of ``space``.
    """
    u = np.asarray(u, dtype=np.float64)
    if u.shape != (space.n_dofs,):
        raise ValueError(f"u has shape {u.shape}: one value per degree of freedom, "
                         f"({space.n_dofs},), is needed")
    if markers.base_elements is None or markers.count == 0:
        return None
    el, lam, w = markers.base_elements, markers.base_lam, markers.base_weights
    p, k = el.shape
    # the recovery's patches: every skin element sharing a vertex with a base point's element
    touched = np.zeros(space.n_vertices, dtype=bool)
    touched[space.elements[np.unique(el), :4]] = True
    skin = np.asarray(skin_elements)
    patch = skin[touched[space.elements[skin, :4]].any(axis=1)]
    recovered = recovered_gradient(space, u, patch)
    vert = space.elements[el.ravel(), :4]
    g_star = np.einsum("ni,nij->nj", lam.reshape(-1, 4), recovered[vert])
    g_h = (gradient_operator(space, el.ravel(), lam.reshape(-1, 4)) @ u).reshape(-1, 9)
    d = (g_h - g_star).reshape(p, k, 9)
    rot = 0.5 * np.stack([d[..., a] - d[..., b] for a, b in _CURL], axis=-1)  # (p, k, 3)
    lever = np.linalg.norm(markers.levers_mm, axis=1)
    return lever * np.sqrt(np.einsum("pk,pk->p", (rot**2).sum(axis=2), w))


def stuck_marker_errors(errors: np.ndarray, touch_states: dict[int, np.ndarray],
                        markers: Markers, space: Space, skin: np.ndarray) -> np.ndarray:
    """``errors`` (the markers' estimates at the solution) with those of the pins whose end is
    stuck on the window replaced by their estimate where the end was anchored
    (``touch_states``, :attr:`~.neohookean.solver.NeoHookeanResult.touch_states`): a stuck end
    keeps its anchor, so its marker carries the error it had there (docs/fem.md, "The markers'
    error"; the end's tilt about its anchored points after the touch is left out). At the
    solution the skin under a held pin's base carries the rod's push, whose gradient jumps
    dominate the estimate there (with the rods' earlier point coupling they did not shrink
    with the mesh; with the base averages they do, 0.33 -> 0.054 mm for pin 9 at the corner
    pose, 2 mm, sliding, docs/convergence.md)."""
    out = errors.copy()
    groups: dict[int, tuple[np.ndarray, list[int]]] = {}
    for pin, u in touch_states.items():  # pins anchored in one step share one state
        groups.setdefault(id(u), (u, []))[1].append(pin)
    for u, pins in groups.values():
        out[pins] = marker_error_estimate(markers, space, u, skin)[pins]
    return out
