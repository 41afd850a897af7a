"""Large-deformation reference: compressible neo-Hookean pad with the same frictionless contact.

Strain energy per reference volume (``F = I + grad u``, ``J = det F``, ``I1 = tr F'F``)::

    W = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2
    P = mu (F - F^-T) + lam ln J F^-T                      (first Piola-Kirchhoff)

which reduces to linear elasticity with the same Lamé moduli at small strain (the tangent at
``u = 0`` is the linear stiffness exactly, with the same quadrature). Equilibrium with contact
is solved by Newton's method in which every iteration is a *linear* contact problem, solved
exactly: with the tangent ``K_t`` (factorised once per iteration) and the out-of-balance
increment ``du0 = -K_t^-1 f_int(u)``, the contact forces ``f_c`` make the linearised gaps of
``x + du0 + K_t^-1 f_c`` complementary (:func:`~.contact.solve_contact`, primal-dual active
set with the exact NNLS fallback, closest-point updates for curved indenters), and
``u += alpha (du0 + K_t^-1 f_c)``; ``alpha`` halves until every ``J > 0``. It stops when the
active set repeats and the increment is below ``tol.geometry_mm``. The depth is applied in
load steps (0.5 mm), halved on failure; failure with ``tol.max_load_steps`` steps raises
:class:`~.contact.ContactError` naming the pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .contact import ContactError, ContactSolution, solve_contact
from .elasticity import Factor, element_dofs
from .elements import quadrature, shape_gradients
from .full import FullOperator
from .indenters import Placement
from .model import ElasticBody
from .tolerances import TOL, Tolerances

_LOAD_STEP_MM = 0.5  # initial depth increment


@dataclass(frozen=True)
class NeoHookeanResult:
    """u : (n_dofs,) mm; contact : the final contact on the candidates; iterations : Newton
    iterations over all load steps; load_steps : steps used."""

    u: np.ndarray
    contact: ContactSolution
    iterations: int
    load_steps: int


class NeoHookeanBody:
    """Residual and tangent of the neo-Hookean pad, vectorised over elements and points."""

    def __init__(self, body: ElasticBody) -> None:
        space = body.space
        self.body = body
        q_lam, q_w = quadrature(2 * (space.order - 1))
        grad_lam, vol = space.element_geometry()
        self.grads = shape_gradients(space.order, q_lam, grad_lam)  # (m, q, nl, 3)
        self.weights = q_w[None, :] * np.abs(vol)[:, None]  # (m, q)
        self.dofs = element_dofs(space)  # (m, 3 nl)
        nd = self.dofs.shape[1]
        self.rows = np.repeat(self.dofs, nd, axis=1).ravel()
        self.cols = np.tile(self.dofs, (1, nd)).ravel()
        self.lam, self.mu = body.lam, body.mu

    def kinematics(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ue = u[self.dofs].reshape(len(self.dofs), -1, 3)  # (m, nl, 3)
        F = np.eye(3) + np.einsum("mai,mqaj->mqij", ue, self.grads)
        return F, np.linalg.det(F)

    def min_jacobian(self, u: np.ndarray) -> float:
        return float(self.kinematics(u)[1].min())

    def residual(self, u: np.ndarray, *, tangent: bool = False
                 ) -> tuple[np.ndarray, sp.csr_matrix | None]:
        """Internal force (n_dofs,) mN and, if asked, the tangent stiffness (mN/mm)."""
        F, J = self.kinematics(u)
        if J.min() <= 0:
            raise FloatingPointError("inverted element")
        Finv = np.linalg.inv(F)
        lnJ = np.log(J)
        lam, mu = self.lam[:, None], self.mu[:, None]
        FinvT = np.swapaxes(Finv, 2, 3)
        P = mu[..., None, None] * (F - FinvT) + (lam * lnJ)[..., None, None] * FinvT
        fe = np.einsum("mq,mqij,mqaj->mai", self.weights, P, self.grads)
        n = self.body.space.n_dofs
        f = np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=n)
        if not tangent:
            return f, None
        w = self.weights
        B = np.einsum("mqaj,mqji->mqai", self.grads, Finv)  # spatial gradients
        lap = np.einsum("mq,mqak,mqbk->mab", w * mu, self.grads, self.grads)
        t2 = np.einsum("mq,mqai,mqbk->maibk", w * lam, B, B)
        t3 = np.einsum("mq,mqak,mqbi->maibk", w * (mu - lam * lnJ), B, B)
        ke = t2 + t3 + lap[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
        K = sp.csr_matrix((ke.ravel(), (self.rows, self.cols)), shape=(n, n))
        return f, K


def solve_neo_hookean(body: ElasticBody, placement: Placement, depth_mm: float, *,
                      label: str = "", tol: Tolerances = TOL) -> NeoHookeanResult:
    """Press the neo-Hookean pad with a placed indenter (load-stepped Newton).

    Parameters
    ----------
    body : the discretised pad (materials, space)
    placement : the indenter at the final depth
    depth_mm : that depth beyond first contact (> 0); load steps move the indenter from first
        contact to ``placement`` along the approach axis
    label : named in error messages (the pose)
    tol : tolerances

    Raises
    ------
    ContactError
        Newton did not converge even with ``tol.max_load_steps`` load steps.
    """
    nh = NeoHookeanBody(body)
    m = placement.approach
    origin_first = placement.origin_mm + depth_mm * m  # the indenter at first contact
    u = np.zeros(body.space.n_dofs)
    active = np.zeros(0, dtype=np.int64)
    contact = None
    done, step, iterations, steps = 0.0, min(depth_mm, _LOAD_STEP_MM), 0, 0
    while done < depth_mm - 1e-12:
        target = min(depth_mm, done + step)
        trial = Placement(placement.indenter, placement.rotation, origin_first - target * m,
                          placement.contact_point_mm, placement.max_depth_mm)
        try:
            u_new, contact_new, its = _newton(nh, trial, u, active, label, tol)
        except _NoConvergence:
            step /= 2
            steps += 1
            if steps > tol.max_load_steps:
                raise ContactError(
                    f"{label or 'neo-Hookean solve'}: Newton did not converge even with load "
                    f"steps of {step * 2:.3g} mm (reached depth {done:.3g} of {depth_mm:.3g} mm)"
                ) from None
            continue
        iterations += its
        steps += 1
        u, contact, done = u_new, contact_new, target
        active = contact.active
    if contact is None:  # depth 0: touching, no force
        cand = body.space.candidates
        g, _ = placement.gap(body.space.nodes[cand])
        contact = ContactSolution(np.zeros((len(cand), 3)), np.zeros(0, dtype=np.int64),
                                  np.zeros((0, 3)), np.zeros(0), g, 0.0, 0, 0)
    return NeoHookeanResult(u, contact, iterations, steps)


class _NoConvergence(Exception):
    pass


def _newton(nh: NeoHookeanBody, placement: Placement, u0: np.ndarray, active0: np.ndarray,
            label: str, tol: Tolerances) -> tuple[np.ndarray, ContactSolution, int]:
    body = nh.body
    free = body.free
    cand = body.space.candidates.astype(np.int64)
    cdofs = (3 * cand[:, None] + np.arange(3)).ravel()
    rest = body.space.nodes[cand]
    u = u0.copy()
    active = active0
    for it in range(1, tol.newton_max_iter + 1):
        try:
            f_int, k_t = nh.residual(u, tangent=True)
            factor = Factor(k_t[free][:, free])
        except (FloatingPointError, np.linalg.LinAlgError, RuntimeError):
            raise _NoConvergence from None
        du0 = np.zeros(body.space.n_dofs)
        du0[free] = factor.solve(-f_int[free])
        op = FullOperator(body, factor)
        start = rest + (u + du0)[cdofs].reshape(-1, 3)
        try:
            sol = solve_contact(placement, start, op, label=label, tol=tol)
        except ContactError:
            raise _NoConvergence from None
        du = du0 + op.field(sol.active, sol.forces)
        alpha = 1.0
        while nh.min_jacobian(u + alpha * du) <= 0:
            alpha /= 2
            if alpha < 1 / 1024:
                raise _NoConvergence
        u = u + alpha * du
        change = float(np.abs(alpha * du).max())
        same = np.array_equal(np.sort(sol.active), np.sort(active))
        active = sol.active
        if alpha == 1.0 and same and change <= max(tol.geometry_mm, 1e-9):
            x = rest + u[cdofs].reshape(-1, 3)
            g, nu = placement.gap(x)
            forces = sol.pressures[:, None] * nu[active]
            comp = float(np.max(np.abs(sol.pressures * g[active]), initial=0.0))
            final = ContactSolution(u[cdofs].reshape(-1, 3), active, forces, sol.pressures, g,
                                    comp, sol.iterations, sol.geometry_iterations)
            return u, final, it
    raise _NoConvergence
