"""Linear elasticity on the tagged mesh: per-element Lamé moduli, the stiffness matrix
(vectorised over elements), its sparse Cholesky factorisation and the surface compliance.

Units: lengths mm, moduli kPa, so stiffness entries are kPa·mm = mN/mm and forces mN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ...mesh import REGION_SKIN
from ...scene import Scene
from ..discretisation.elements import quadrature, shape_gradients
from ..discretisation.space import Space

_CHUNK = 20_000  # elements assembled per vectorised batch (bounds the memory)


def lame(youngs_kpa: float, poisson: float) -> tuple[float, float]:
    """Lamé parameters ``(lambda, mu)`` in kPa from Young's modulus (kPa) and Poisson's ratio."""
    lam = youngs_kpa * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    return lam, youngs_kpa / (2.0 * (1.0 + poisson))


def element_moduli(space: Space, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Per-element Lamé parameters ``lam, mu`` (m,) kPa: the skin's in skin elements, the gel's
    elsewhere (a block is all gel)."""
    skin = lame(scene.skin.youngs_modulus_kpa, scene.skin.poisson_ratio)
    gel = lame(scene.gel.youngs_modulus_kpa, scene.gel.poisson_ratio)
    is_skin = (space.regions == REGION_SKIN) & (not scene.is_block)
    return np.where(is_skin, skin[0], gel[0]), np.where(is_skin, skin[1], gel[1])


def element_dofs(space: Space, elements: np.ndarray | slice = slice(None)) -> np.ndarray:
    """(m, 3 * n_local) global dofs of elements, ordered (local node, component)."""
    nodes = space.elements[elements].astype(np.int64)
    return (3 * nodes[:, :, None] + np.arange(3)).reshape(len(nodes), -1)


def stiffness(space: Space, lam: np.ndarray, mu: np.ndarray) -> sp.csr_matrix:
    """The global stiffness matrix (n_dofs, n_dofs), mN/mm, symmetric positive semi-definite.

    Exact integration for affine elements (the integrand is a polynomial of degree
    ``2 (order - 1)``).
    """
    q_lam, q_w = quadrature(2 * (space.order - 1))
    grad_lam, vol = space.element_geometry()
    eye = np.eye(3)
    out = sp.csr_matrix((space.n_dofs, space.n_dofs))
    for start in range(0, len(space.elements), _CHUNK):
        s = slice(start, start + _CHUNK)
        g = shape_gradients(space.order, q_lam, grad_lam[s])  # (m, q, nl, 3)
        w = q_w[None, :] * np.abs(vol[s])[:, None]  # (m, q)
        vol_term = np.einsum("mq,mqai,mqbj->maibj", w * lam[s][:, None], g, g)
        dev = np.einsum("mq,mqaj,mqbi->maibj", w * mu[s][:, None], g, g)
        lap = np.einsum("mq,mqak,mqbk->mab", w * mu[s][:, None], g, g)
        ke = vol_term + dev + lap[:, :, None, :, None] * eye[None, None, :, None, :]
        m, nl = ke.shape[:2]
        dofs = element_dofs(space, s)
        rows = np.repeat(dofs, 3 * nl, axis=1)
        cols = np.tile(dofs, (1, 3 * nl))
        out = out + sp.csr_matrix((ke.reshape(m, -1).ravel(), (rows.ravel(), cols.ravel())),
                                  shape=out.shape)
    out.sum_duplicates()
    return out


def cholmod_available() -> bool:
    """True if scikit-sparse's CHOLMOD can be imported (otherwise SuperLU is used)."""
    try:
        import sksparse.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


def cholmod_blas_is_reference() -> bool:
    """True if the BLAS that CHOLMOD loaded is the unoptimised reference (netlib) one, as on a
    Debian system without OpenBLAS: supernodal factors then solve ~3x slower than simplicial
    ones. Read from this process's memory map (Linux); False when it cannot be told."""
    if not cholmod_available():
        return False
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return False
    libs = {line.split()[-1] for line in maps.splitlines() if "libblas.so" in line}
    return any("/blas/" in lib and "openblas" not in lib for lib in libs)


class Factor:
    """A sparse factorisation of a symmetric positive-definite matrix.

    CHOLMOD (scikit-sparse) when installed, else SciPy's SuperLU.

    Parameters
    ----------
    matrix : (n, n) sparse SPD matrix
    backend : "auto", "cholmod" or "splu"
    many_solves : CHOLMOD with the reference BLAS only: use a simplicial factor, whose
        multi-RHS solves are ~3x faster there (at ~2x the factorisation time)
    """

    def __init__(self, matrix: sp.spmatrix, *, backend: str = "auto",
                 many_solves: bool = True) -> None:
        matrix = sp.csc_matrix(matrix)
        if backend == "auto":
            backend = "cholmod" if cholmod_available() else "splu"
        if backend == "cholmod":
            from sksparse.cholmod import CholmodError, cholesky

            simplicial = many_solves and cholmod_blas_is_reference()
            try:
                self._factor = cholesky(matrix, ordering_method="metis",
                                        mode="simplicial" if simplicial else "supernodal")
            except CholmodError as exc:
                raise np.linalg.LinAlgError(f"CHOLMOD: {exc}") from exc
            self._solve = self._factor
        elif backend == "splu":
            from scipy.sparse.linalg import splu

            self._factor = splu(matrix, permc_spec="MMD_AT_PLUS_A")
            self._solve = self._factor.solve
        else:
            raise ValueError(f"backend={backend!r} is not allowed: 'auto', 'cholmod' or 'splu'")
        self.backend = backend
        self.shape = matrix.shape

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Solve for (n,) or (n, k) right-hand sides."""
        return np.asarray(self._solve(np.asarray(rhs, dtype=np.float64)))


def schur_inverse(matrix: sp.spmatrix, last: np.ndarray, extra: sp.spmatrix | None = None,
                  *, extra_inverse: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None] | tuple[
                      np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(A^-1)[last][:, last]`` and ``(extra A^-1)[:, last]`` by one partial factorisation.

    The unknowns ``last`` are ordered after all others (the others by METIS), so the trailing
    block of the Cholesky factor ``L`` is the Cholesky factor of the Schur complement ``S`` of
    the others, and ``(A^-1)_last = S^-1 = L_ss^-T L_ss^-1`` (dense LAPACK ``trtri`` +
    ``lauum``). With ``Z = L^-1 extra'`` (forward solves only), ``extra A^-1 E_last =
    Z_last' L_ss^-1``; and, with ``extra_inverse``, ``extra A^-1 extra' = Z' Z``. Requires
    CHOLMOD.

    Parameters
    ----------
    matrix : (n, n) sparse symmetric positive definite
    last : (k,) int, distinct indices
    extra : optional (r, n) sparse rows
    extra_inverse : also return ``extra A^-1 extra'``

    Returns
    -------
    inverse : (k, k) float, symmetric
    response : (r, k) float or None
    extra_block : (r, r) float or None, only with ``extra_inverse``
    """
    from scipy.linalg import lapack
    from sksparse.cholmod import analyze, cholesky

    a = sp.csc_matrix(matrix)
    n, k = a.shape[0], len(last)
    rest = np.setdiff1d(np.arange(n), last)
    inner = a[rest][:, rest].tocsc()
    perm = np.concatenate([rest[analyze(inner, ordering_method="metis").P()], last])
    del inner
    factor = cholesky(a[perm][:, perm].tocsc(), ordering_method="natural", mode="supernodal")
    if not np.array_equal(factor.P(), np.arange(n)):
        raise RuntimeError("CHOLMOD reordered a natural-order factor")
    z_last = extra_block = None
    if extra is not None and extra.shape[0]:
        rhs = np.asfortranarray(sp.csr_matrix(extra)[:, perm].T.toarray())
        z = factor.solve_L(rhs, use_LDLt_decomposition=False)
        del rhs
        if extra_inverse:
            extra_block = z.T @ z
            extra_block = 0.5 * (extra_block + extra_block.T)
        z_last = z[n - k:]
        del z
    low = factor.L()
    del factor
    tail = np.asfortranarray(low[n - k:, n - k:].toarray())
    del low
    linv, info = lapack.dtrtri(tail, lower=1, overwrite_c=1)
    if info:
        raise np.linalg.LinAlgError(f"trtri failed (info={info})")
    response = None if z_last is None else z_last.T @ linv  # linv is lower triangular
    inv, info = lapack.dlauum(linv, lower=1, overwrite_c=1)
    if info:
        raise np.linalg.LinAlgError(f"lauum failed (info={info})")
    inv += np.tril(inv, -1).T  # lauum filled the lower triangle; the upper one was zero
    if extra_inverse:
        return np.ascontiguousarray(inv), response, extra_block
    return np.ascontiguousarray(inv), response
