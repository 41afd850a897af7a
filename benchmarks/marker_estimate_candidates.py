"""Which per-marker error estimate flags the pins that local refinement moves?

docs/convergence.md, "An estimate per marker": five candidates computed from one P2 field on the
1 mm mesh (the reference physics: neo-Hookean, rods stopped by the window) and compared with
how far a refined press moved each marker:

- ``P2 - P1``: the marker from the field against the marker from its vertex values alone,
  interpolated linearly (a hierarchical indicator);
- the others compare the field's gradient with the skin's recovered one (Zienkiewicz-Zhu:
  :func:`tactip_sim.fem.markers.error.recovered_gradient`), as the tip turned by the recovered
  mean gradient, as the root mean square of the difference over a 2 mm ball or over the pin's
  base, or as that of its rotation part over the base (the product's estimate,
  :func:`tactip_sim.fem.markers.error.marker_error_estimate`).

Usage::

    python benchmarks/marker_estimate_candidates.py --out /tmp/cand \\
        --truth /tmp/localref/1_mm_refined_0.45_r1.5.npz

presses the 1 mm mesh at the pose (default: the corner pose at the training depth), keeps its
field in ``OUT`` (a rerun reuses it) and prints each candidate's rank correlation with what the
truths (presses stored by ``convergence_local_refinement.py`` at the same pose) moved, its
values at the pins that moved more than ``--moved`` mm, and how many pins reach the smallest of
those values.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from convergence_rod_quadrature import pose_parser

from tactip_sim.commands.args import float_in

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
BALL_MM = 2.0  # the ball candidate's radius around each root


def _sim():
    import tactip_sim as ts

    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={
        "mesh_edge_mm": 1.0, "element_order": 2, "material_model": "neo_hookean"})
    return ts.Simulator(scene)


def field(sim, pose, out: Path) -> np.ndarray:
    """The 1 mm press's full field (n_dofs,), solved or read from ``out``."""
    import tactip_sim as ts
    from tactip_sim.fem.contact.indenters import place
    from tactip_sim.fem.neohookean.solver import solve_neo_hookean

    path = out / "field_1mm.npz"
    if path.is_file():
        with np.load(path) as z:
            if not np.allclose(z["pose"], pose):
                raise SystemExit(f"{path} holds the field at pose {z['pose'].tolist()}: give "
                                 "another --out")
            return z["u"]
    p = ts.Pose(*pose)
    t0 = time.perf_counter()
    placement = place(sim.indenter, p, sim._cand_rest,
                      skin_thickness_mm=sim.body.skin_thickness_mm)
    u = solve_neo_hookean(sim.body, placement, p.depth_mm, label=str(p), tol=sim.tol,
                          markers=sim.body.markers).u
    print(f"1 mm press: {time.perf_counter() - t0:.0f} s")
    tmp = out / ".field_1mm.npz"
    np.savez(tmp, u=u, pose=np.array(pose))
    tmp.replace(path)
    return u


def candidates(sim, u: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The field's markers (p, 3) and each candidate's value per marker (p,), mm."""
    from scipy.spatial import cKDTree

    import tactip_sim as ts
    from tactip_sim.fem.discretisation.space import gradient_operator
    from tactip_sim.fem.markers.error import (
        _vertex_gradients,
        marker_error_estimate,
        recovered_gradient,
    )
    from tactip_sim.mesh import REGION_SKIN
    from tactip_sim.mesh.topology import tet_volumes

    space, mk = sim.body.space, sim.body.markers
    skin = np.flatnonzero(sim.mesh.regions == REGION_SKIN)
    g_star = recovered_gradient(space, u, skin)
    markers = mk.from_field(u, finite=True)[0]
    el, lam, w = mk.base_elements, mk.base_lam, mk.base_weights
    p, k = el.shape
    vert = space.elements[el.ravel(), :4]
    at_base = np.einsum("ni,nij->nj", lam.reshape(-1, 4), g_star[vert]).reshape(p, k, 9)
    g_h = (gradient_operator(space, el.ravel(), lam.reshape(-1, 4)) @ u).reshape(p, k, 9)
    out = {}
    nv = space.n_vertices
    p1 = ts.Simulator(ts.replace_in(sim.scene, fidelity={"element_order": 1}), mesh=sim.mesh)
    out["P2 - P1 marker"] = np.linalg.norm(
        markers - p1.body.markers.from_field(u[:3 * nv], finite=True)[0], axis=1)
    mean = np.einsum("pkj,pk->pj", at_base, w).reshape(p, 3, 3)
    uu, _, vt = np.linalg.svd(np.eye(3) + mean)
    anchors = mk.anchors_mm + (mk.operator @ u).reshape(p, 2, 3)[:, 0]
    out["tip from the recovered mean gradient"] = np.linalg.norm(
        anchors + np.einsum("pij,pj->pi", uu @ vt, mk.levers_mm) - markers, axis=1)
    vol = np.abs(tet_volumes(space.nodes[:nv], space.elements[skin, :4]))
    diff = _vertex_gradients(space, u, skin) - g_star[space.elements[skin, :4]]
    per_tet = np.sqrt((diff**2).sum(axis=2).mean(axis=1))
    tree = cKDTree(space.nodes[space.elements[skin, :4]].mean(axis=1))
    ball = np.zeros(p)
    for i in range(p):
        idx = tree.query_ball_point(mk.roots_mm[i], BALL_MM)
        ball[i] = mk.length_mm * np.sqrt(np.average(per_tet[idx] ** 2, weights=vol[idx]))
    out[f"gradient RMS over a {BALL_MM:g} mm ball x lever"] = ball
    out["gradient RMS over the base x lever / 2"] = 0.5 * mk.length_mm * np.sqrt(
        np.einsum("pk,pk->p", ((g_h - at_base) ** 2).sum(axis=2), w))
    out["rotation RMS over the base x lever (product)"] = marker_error_estimate(mk, space, u, skin)
    return markers, out


def main() -> None:
    ap = pose_parser(__doc__)
    ap.add_argument("--truth", type=Path, nargs="+", required=True,
                    help="refined presses at the same pose (convergence_local_refinement.py)")
    ap.add_argument("--moved", type=float_in(1e-4, 1.0), default=0.01,
                    help="a pin counts as moved beyond this, mm (default 0.01)")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    pose = (a.roll, a.pitch, a.depth)
    sim = _sim()
    markers, cands = candidates(sim, field(sim, pose, a.out))

    def rank(x):
        return np.argsort(np.argsort(x))

    for path in a.truth:
        with np.load(path) as z:
            if "pose" in z.files and not np.allclose(z["pose"], pose):
                raise SystemExit(f"{path} is a press at pose {z['pose'].tolist()}, not {pose}")
            moved = np.linalg.norm(markers - z["markers"], axis=1)
        big = np.flatnonzero(moved > a.moved)
        print(f"{path}: moved more than {a.moved:g} mm: "
              + ", ".join(f"#{i} {moved[i]:.4f}" for i in big))
        for name, ind in cands.items():
            rho = np.corrcoef(rank(ind), rank(moved))[0, 1]
            floor = ind[big].min() if len(big) else np.nan
            print(f"  {name:<46} rank corr {rho:.2f}; at the moved pins "
                  + ", ".join(f"#{i} {ind[i]:.4f}" for i in big)
                  + f"; pins at or above the smallest: {int((ind >= floor).sum())}")


if __name__ == "__main__":
    main()
