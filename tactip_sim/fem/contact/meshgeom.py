"""Inside/outside of a closed triangle mesh by the generalised winding number, for
:class:`~tactip_sim.fem.contact.indenters.MeshIndenter`.

trimesh gives the indenter its closest points and ray casts; its inside test
(``Trimesh.contains``, parity of ray hits) is not used: it called points 1e-9 mm inside the
bundled icosphere and capsule outside (1918 of 1922 and 862 of 866 such points), and it retries
ambiguous rays in a random direction, so its answer on the surface changes from run to run.
Contact needs the side right just there: a node a nanometre inside the indenter is penetrating.
The winding number is a sum of solid angles, exact and deterministic at any distance.

The points are processed in chunks against all triangles, so memory stays bounded; no Python
loop over points or triangles.
"""

from __future__ import annotations

import numpy as np

_PAIRS_PER_CHUNK = 2_000_000


def _chunks(n_points: int, n_tris: int):
    step = max(1, _PAIRS_PER_CHUNK // max(n_tris, 1))
    for start in range(0, n_points, step):
        yield slice(start, min(start + step, n_points))


def winding_number(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(n,) generalised winding number (1 inside, 0 outside a closed outward-oriented mesh),
    by the Van Oosterom–Strackee solid angle of every triangle."""
    out = np.zeros(len(points))
    for s in _chunks(len(points), len(tris)):
        r = tris[None, :, :, :] - points[s][:, None, None, :]  # (k, f, 3, 3)
        ln = np.linalg.norm(r, axis=3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = ln[:, :, 0], ln[:, :, 1], ln[:, :, 2]
        num = np.einsum("kfi,kfi->kf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("kfi,kfi->kf", a, b) * lc
               + np.einsum("kfi,kfi->kf", b, c) * la + np.einsum("kfi,kfi->kf", c, a) * lb)
        out[s] = np.arctan2(num, den).sum(axis=1) / (2.0 * np.pi)
    return out
