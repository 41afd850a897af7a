"""Pins held by the gel: an elastic beam bonded to the skin, on the gel as a foundation.

The two other pin models are limits. ``embedded`` tips are material points of the gel (a pin
as soft as the gel); ``rod`` tips swing rigidly with the skin's rotation under the base (a pin
infinitely stiff against the gel). The Bristol pins are neither: rubber rods printed with the
skin (its modulus, ~30 times the gel's) as thick as they are long. Modelled here (``beam``):
each pin is an Euler–Bernoulli beam (bending) and a bar (stretch) clamped to the skin by its base
— where it follows the rod's rigid motion, the base's mean displacement and rotation — and held
along its length by the surrounding gel as a Winkler foundation whose displacement is the gel's
own field on the pin's axis:

    EI v'''' + k (v - g) = 0,   EA u'' - k_a (u - g_a) = 0   on 0 < s < L,
    v(0) = v'(0) = 0, v''(L) = v'''(L) = 0;   u(0) = 0, u'(L) = 0,

``v``, ``u`` the pin's transverse and axial displacement and ``g``, ``g_a`` the gel's, all
relative to the rod's rigid motion. The tip is the rod's tip plus ``(v(L), u(L))``: a rigid pin
(``k -> 0``) gives the rod, an infinitely soft one (``k -> oo``) the gel's displacement at the
tip, the embedded model.

The coefficients (:func:`gel_coupling`, every one from the scene's moduli and the pin's size):

- ``EI = E_pin pi d^4 / 64``, ``EA = E_pin pi d^2 / 4``, with ``E_pin`` the skin's modulus: the
  pins are printed in the skin's material (shared/SENSOR.md).
- ``k = 0.65 (E_g d^4 / (E_pin I))^(1/12) E_g / (1 - nu_g^2)``: the modulus of subgrade reaction
  of a beam of width ``d`` in an elastic solid, A. B. Vesic, "Bending of beams resting on
  isotropic elastic solid", J. Eng. Mech. Div. ASCE 87(EM2), 35–53, 1961.
- ``k_a = 2 pi G_g / ln(r_m / r_0)``, ``r_m = 2.5 L (1 - nu_g)``: the shaft stiffness of an axially
  loaded pile, M. F. Randolph & C. P. Wroth, "Analysis of deformation of vertically loaded
  piles", J. Geotech. Eng. Div. ASCE 104(GT12), 1465–1488, 1978.

The coupling is one way: the gel's field is the solve's, computed without the pins' own
stiffness (the pins fill ~40 % of the gel's cross-section under the skin on the 331-pin tip;
their push back on the gel is not modelled). The ODEs are solved once per scene on a 1-D mesh
of Hermite (bending) and linear (stretch) elements, the gel's displacement sampled at
:data:`SAMPLES` + 1 points of the axis and interpolated linearly between them: the tip is then
a fixed linear combination of those samples (:func:`tip_weights`), and the pins' operator
stays linear in the nodal displacements, so the reduced contact model stores it as it stores
the rods'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

SAMPLES = 4
"""Intervals of the pin's axis at whose ends the gel's displacement is sampled (the root's
included): on the pad's P2 meshes (1.5–3 mm elements against a 2.5 mm pin) the field along the
pin is near quadratic, which 5 points carry."""
ELEMENTS = 32
"""1-D elements over the pin (Hermite cubics for the bending, linear for the stretch): on the
scenes' 1.2 mm x 2.5 mm pins the tip's transverse weights change by < 1e-7 from 32 to 128
elements and the axial ones by 2e-6 (of a sum of 0.104); the tests hold them to the exact
solution within 1e-5 and 1e-3."""


@dataclass(frozen=True)
class Coupling:
    """A pin's stiffnesses (mm, kPa: forces in mN).

    bending : EI, mN mm^2
    lateral : k, the gel's transverse foundation modulus, kPa (mN per mm of length per mm)
    stretch : EA, mN
    axial : k_a, the gel's axial (shaft) foundation modulus, kPa
    """

    bending: float
    lateral: float
    stretch: float
    axial: float


def gel_coupling(diameter_mm: float, length_mm: float, pin_youngs_kpa: float,
                 gel_youngs_kpa: float, gel_poisson: float) -> Coupling:
    """The pin's stiffnesses from its size and the moduli (module docstring: Vesic 1961,
    Randolph & Wroth 1978).

    Raises
    ------
    ValueError
        a size or modulus that is not positive, or a Poisson ratio outside (-1, 0.5).
    """
    for name, v in (("pins.diameter_mm", diameter_mm), ("pins.length_mm", length_mm),
                    ("skin.youngs_modulus_kpa", pin_youngs_kpa),
                    ("gel.youngs_modulus_kpa", gel_youngs_kpa)):
        if not np.isfinite(v) or v <= 0.0:
            raise ValueError(f"{name}={v!r} must be a positive number for pins.model='beam'")
    if not -1.0 < gel_poisson < 0.5:
        raise ValueError(f"gel.poisson_ratio={gel_poisson!r} is out of range: allowed (-1, 0.5)")
    d, e_p, e_g = float(diameter_mm), float(pin_youngs_kpa), float(gel_youngs_kpa)
    inertia = np.pi * d**4 / 64.0
    lateral = 0.65 * (e_g * d**4 / (e_p * inertia)) ** (1.0 / 12.0) * e_g / (1.0 - gel_poisson**2)
    shear = e_g / (2.0 * (1.0 + gel_poisson))
    reach = 2.5 * length_mm * (1.0 - gel_poisson)
    # r_m floored at 2 d (r_m / r_0 >= 4): a stubby pin keeps a finite, positive shaft
    # stiffness; inactive on the scenes' pins (r_m = 3.4 mm against 2.4 mm)
    zeta = np.log(max(reach, 2.0 * d) / (0.5 * d))
    return Coupling(bending=e_p * inertia, lateral=lateral, stretch=e_p * np.pi * d**2 / 4.0,
                    axial=2.0 * np.pi * shear / zeta)


def _hat(s: np.ndarray, length_mm: float, samples: int) -> np.ndarray:
    """(len(s), samples + 1): the linear interpolation weights of the samples at ``s``."""
    t = np.clip(np.asarray(s) / length_mm * samples, 0.0, samples)
    j = np.minimum(np.floor(t).astype(int), samples - 1)
    f = t - j
    out = np.zeros((len(t), samples + 1))
    out[np.arange(len(t)), j] = 1.0 - f
    out[np.arange(len(t)), j + 1] = f
    return out


def tip_weights(length_mm: float, coupling: Coupling, *, samples: int = SAMPLES,
                elements: int = ELEMENTS) -> tuple[np.ndarray, np.ndarray]:
    """The tip's displacement relative to the rod's rigid motion, as weights of the gel's
    relative displacement at the ``samples + 1`` points ``s_j = j L / samples`` of the axis.

    Returns
    -------
    transverse : (samples + 1,) ``v(L) = sum_j transverse[j] g(s_j)`` (each transverse
        direction alike)
    axial : (samples + 1,) ``u(L) = sum_j axial[j] g_a(s_j)``
    """
    if not np.isfinite(length_mm) or length_mm <= 0.0:
        raise ValueError(f"pins.length_mm={length_mm!r} must be a positive number")
    h = length_mm / elements
    xg, wg = np.polynomial.legendre.leggauss(4)
    xi, wq = 0.5 * (xg + 1.0), 0.5 * wg * h  # on [0, 1], weights for ds
    # Hermite cubics on one element (dofs v0, v0', v1, v1'), values and second derivatives
    n = np.stack([1 - 3 * xi**2 + 2 * xi**3, h * (xi - 2 * xi**2 + xi**3),
                  3 * xi**2 - 2 * xi**3, h * (-xi**2 + xi**3)], axis=1)
    b = np.stack([-6 + 12 * xi, h * (-4 + 6 * xi), 6 - 12 * xi, h * (-2 + 6 * xi)], axis=1) / h**2
    ke = coupling.bending * (b.T * wq) @ b + coupling.lateral * (n.T * wq) @ n
    nb = 2 * (elements + 1)
    kb = np.zeros((nb, nb))
    fb = np.zeros((nb, samples + 1))
    # linear elements for the bar (dofs u0, u1)
    nl = np.stack([1 - xi, xi], axis=1)
    dl = np.array([-1.0, 1.0]) / h
    kle = coupling.stretch * np.outer(dl, dl) * h + coupling.axial * (nl.T * wq) @ nl
    kl = np.zeros((elements + 1, elements + 1))
    fl = np.zeros((elements + 1, samples + 1))
    for e in range(elements):
        hat = _hat(h * (e + xi), length_mm, samples)  # (q, samples + 1)
        sb = slice(2 * e, 2 * e + 4)
        kb[sb, sb] += ke
        fb[sb] += coupling.lateral * (n.T * wq) @ hat
        sl = slice(e, e + 2)
        kl[sl, sl] += kle
        fl[sl] += coupling.axial * (nl.T * wq) @ hat
    # clamped root: v(0) = v'(0) = 0; u(0) = 0; free tip
    vb = np.linalg.solve(kb[2:, 2:], fb[2:])
    vl = np.linalg.solve(kl[1:, 1:], fl[1:])
    return vb[-2], vl[-1]


def beam_operator(rod: sp.csr_matrix, gel: sp.csr_matrix, anchors: np.ndarray,
                  points: np.ndarray, levers: np.ndarray, directions: np.ndarray,
                  transverse: np.ndarray, axial: np.ndarray
                  ) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """(3 p, n_dofs) each, the anchor shift ``U`` and turn ``w`` of the rods' form (the rows of
    :func:`~.kinematics.rod_operator`) that carry each tip where the beam's is.

    Parameters
    ----------
    rod : (6 p, n_dofs) the rods' operator (:func:`~.kinematics.rod_operator`)
    gel : (3 p (m + 1), n_dofs) the gel's displacement at the sample points, pin-major
    anchors : (p, 3) mm, the rods' anchors (where ``U`` applies)
    points : (p, m + 1, 3) mm, the sample points on each pin's axis
    levers : (p, 3) mm, each tip from its anchor at rest
    directions : (p, 3) unit pin axes
    transverse, axial : (m + 1,) :func:`tip_weights`

    The correction ``D = sum_j (transverse_j (I - a a') + axial_j a a') g_j``, ``g_j`` the gel's
    displacement at point ``j`` less the rod's rigid motion there (``U + w x (x_j - c)``),
    enters as ``U += (D . l^) l^`` and ``w += l x D / |l|^2`` (``l`` the lever): to first
    order the rod's tip ``U + w x l`` then moves by ``D``.
    """
    p, m1 = points.shape[:2]
    rod = sp.csr_matrix(rod)
    shift_rows = (6 * np.arange(p)[:, None] + np.arange(3)).ravel()
    turn_rows = shift_rows + 3
    shift, turn = rod[shift_rows], rod[turn_rows]

    def blocks(mats: np.ndarray) -> sp.csr_matrix:
        """(3 p, 3 p) block diagonal from (p, 3, 3)."""
        return sp.block_diag(list(mats), format="csr")

    a = directions
    along = np.einsum("pi,pj->pij", a, a)
    across = np.eye(3) - along
    correction = sp.csr_matrix((3 * p, rod.shape[1]))
    for j in range(m1):
        rows = (3 * (np.arange(p) * m1 + j)[:, None] + np.arange(3)).ravel()
        arm = points[:, j] - anchors  # w x arm = -[arm]x w
        cross = np.zeros((p, 3, 3))
        cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -arm[:, 2], arm[:, 1], -arm[:, 0]
        cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = arm[:, 2], -arm[:, 1], arm[:, 0]
        relative = gel[rows] - shift + blocks(cross) @ turn
        correction = correction + blocks(transverse[j] * across + axial[j] * along) @ relative
    lever_len2 = np.einsum("pi,pi->p", levers, levers)
    unit = levers / np.sqrt(lever_len2)[:, None]
    lc = np.zeros((p, 3, 3))  # [l]x / |l|^2
    lc[:, 0, 1], lc[:, 0, 2], lc[:, 1, 2] = -levers[:, 2], levers[:, 1], -levers[:, 0]
    lc[:, 1, 0], lc[:, 2, 0], lc[:, 2, 1] = levers[:, 2], -levers[:, 1], levers[:, 0]
    lc /= lever_len2[:, None, None]
    new_shift = shift + blocks(np.einsum("pi,pj->pij", unit, unit)) @ correction
    new_turn = turn + blocks(lc) @ correction
    return new_shift.tocsr(), new_turn.tocsr()
