"""Does a held pin load the skin at a point, and is that what keeps 2 mm from converging?

docs/convergence.md: at 2 mm depth and the corner pose three pins' ends reach the window, and
the plate's force falls with every finer mesh (P2, ends stuck: 8.90, 8.75, 8.58, 8.37 N from 2
to 1 mm; refined to 0.6 mm around seven pins, 7.89 N). A rod's tip is ``root + u(root) + L R
d`` (:mod:`tactip_sim.fem.markers.kinematics`): its translation is the displacement at one point,
the root, and its rotation the skin's gradient averaged at 14 points of its base. When the window
pushes on the rod, that push enters the skin through the same operators: a point force at the
root and point dipoles at the 14 points. A point force has no finite-energy limit in 3-D
elasticity (the displacement under it grows without bound as the mesh is refined), so the
held pins get softer with every refinement and the force they carry never converges.

This study compared that coupling (the model until 2026-11-28) with one averaged over the
pin's bonded base, integrated over the skin's elements (a bump ``(1 - (rho/r)^2)^2`` in the
distance ``rho`` from the pin's axis, ``r`` the pin's radius, through the skin's thickness):
loads that are bounded functionals of the field, with a finite limit. The averaged coupling is
now the product's rod model (:mod:`tactip_sim.fem.markers.kinematics`); the point coupling is
rebuilt here from the earlier model's operators. It presses the corner pose at 2 mm, window
frictionless (a path-independent answer), on the given mesh and on the same mesh refined
around the held pins, with both couplings, and prints the plate's force, the held pins' forces
and how far refinement moved the markers.

Usage::

    python benchmarks/convergence_rod_coupling.py --out DIR                      # P2, 1 mm
    python benchmarks/convergence_rod_coupling.py --out DIR --order 1 --edge 2   # quick

Each press is stored in ``OUT``; a rerun solves only the missing ones.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tactip_sim.commands.args import float_in

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
HELD = (2, 9, 19)  # the pins held by the window at the corner pose, 2 mm (docs/convergence.md)


def point_coupling(markers, space, pad, radius_mm: float, thickness_mm: float):
    """``markers`` (rods) with the earlier model's operators: the root's displacement at the
    root point and the gradient averaged at the 7 x 2 points of the base
    (:func:`convergence_rod_quadrature.disk7_base`), the lever from the root."""
    from convergence_rod_quadrature import disk7_base, mean_gradient

    from tactip_sim.fem.discretisation.space import interpolation_operator, locate
    from tactip_sim.fem.markers.kinematics import rod_operator

    el, lam, _ = locate(space, markers.roots_mm)
    grad = mean_gradient(space, *disk7_base(pad, radius_mm, thickness_mm))
    return replace(markers, operator=rod_operator(interpolation_operator(space, el, lam), grad),
                   gradient=grad, base_elements=None, base_lam=None, base_weights=None,
                   anchors_mm=markers.roots_mm.copy())


def solve(coupling: str, refined: bool, a, out: Path) -> Path:
    import tactip_sim as ts
    from tactip_sim.fem.contact.indenters import place
    from tactip_sim.fem.neohookean.solver import solve_neo_hookean
    from tactip_sim.geometry import build_pad
    from tactip_sim.mesh.local import Refinement, refined_mesh

    path = out / f"{coupling}_{'refined' if refined else 'base'}_p{a.order}_h{a.edge:g}.npz"
    if path.is_file():
        return path
    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={
        "mesh_edge_mm": a.edge, "element_order": a.order, "material_model": "neo_hookean"})
    sim = ts.Simulator(scene)
    mesh = sim.mesh
    if refined:
        roots = build_pad(scene).pins.roots[list(HELD)]
        mesh = refined_mesh(scene, Refinement(tuple(map(tuple, roots)), a.refine_edge, 1.5),
                            base=mesh)
        sim = ts.Simulator(scene, mesh=mesh)
    body = sim.body
    markers = body.markers
    if coupling == "point":  # on the body too: the tangent's pattern reads its rods
        markers = point_coupling(markers, body.space, sim.pad, 0.5 * scene.pins.diameter_mm,
                                 body.skin_thickness_mm)
        body.markers = markers
    pose = ts.Pose(a.roll, a.pitch, a.depth)
    rest = body.space.nodes[body.space.candidates]
    placement = place(ts.Plate(), pose, rest, skin_thickness_mm=body.skin_thickness_mm)
    t0 = time.perf_counter()
    r = solve_neo_hookean(body, placement, pose.depth_mm, markers=markers)
    seconds = time.perf_counter() - t0
    tmp = out / f".{path.name}"
    np.savez(tmp, markers=markers.from_field(r.u, finite=True)[0],
             force=-float(r.contact.forces.sum(axis=0)[2]), pins=np.asarray(r.window_forces),
             tets=len(mesh.tets), seconds=seconds)
    tmp.replace(path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for the presses")
    ap.add_argument("--edge", type=float_in(0.5, 2.5), default=1.0,
                    help="bundled mesh size, mm (default 1)")
    ap.add_argument("--order", type=int, choices=(1, 2), default=2, help="element order")
    ap.add_argument("--refine-edge", type=float_in(0.1, 2.0), default=0.6,
                    help=f"edge within 1.5 mm of the held pins' roots {HELD}, mm (default 0.6)")
    ap.add_argument("--roll", type=float_in(-30.0, 30.0), default=12.0, help="degrees")
    ap.add_argument("--pitch", type=float_in(-30.0, 30.0), default=-8.8, help="degrees")
    ap.add_argument("--depth", type=float_in(0.05, 4.0), default=2.0, help="mm (default 2)")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    runs = {}
    for coupling in ("point", "averaged"):
        for refined in (False, True):
            with np.load(solve(coupling, refined, a, a.out)) as z:
                runs[coupling, refined] = {k: z[k] for k in z.files}
    print(f"pose {a.roll:g} / {a.pitch:g} deg, {a.depth:g} mm, P{a.order}, {a.edge:g} mm mesh, "
          f"refined to {a.refine_edge:g} mm within 1.5 mm of pins {HELD}; window frictionless")
    for coupling in ("point", "averaged"):
        base, fine = runs[coupling, False], runs[coupling, True]
        moved = np.linalg.norm(fine["markers"] - base["markers"], axis=1)
        lead = ", ".join(f"#{i} {moved[i]:.4f}" for i in np.argsort(moved)[::-1][:4])
        held = ", ".join(f"{base['pins'][p]:.0f} -> {fine['pins'][p]:.0f}" for p in HELD)
        print(f"  {coupling:>8}: force {base['force']:.1f} -> {fine['force']:.1f} mN "
              f"({100 * (fine['force'] / base['force'] - 1):+.2f} %), held pins {HELD} "
              f"{held} mN; markers moved {moved.max():.4f} mm ({lead}); "
              f"{int(base['tets'])} -> {int(fine['tets'])} tets, "
              f"{float(base['seconds']):.0f} + {float(fine['seconds']):.0f} s")


if __name__ == "__main__":
    main()
