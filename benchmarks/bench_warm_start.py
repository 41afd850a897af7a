"""Benchmark of the refined neo-Hookean solve started from the coarse answer
(``Simulator.press(initial=)``, what ``fidelity.pin_refinement = "auto"`` does between its
levels): for each pose, the scene's mesh is pressed, refined around the pins whose estimated
marker error exceeds the tolerance (the product's first level,
:mod:`tactip_sim.fem.refinement.refine`), and the refined mesh pressed twice, from rest by load
steps and from the coarse answer carried onto it, one after the other in this process. Prints both
times, their ratio, the Newton iterations and how far apart the two answers are (they should agree
to solver precision: the frictionless, stick-free answer does not depend on the path).

Usage::

    python benchmarks/bench_warm_start.py                 # P2, the bundled 2 mm mesh
    python benchmarks/bench_warm_start.py --order 1       # quick
    python benchmarks/bench_warm_start.py --edge 1.0      # the reference preset's 1 mm mesh
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
# (roll, pitch, depth mm): the protocol's corner at the training depth and at 2 mm (the window
# holds pins 2, 9 and 19 there), the centre of its box at 2 mm and a random pose (seed
# 20261127, docs/convergence.md) at the training depth
POSES = ((12.0, -8.8, 1.0), (12.0, -8.8, 2.0), (4.0, -2.0, 2.0), (-4.2, -8.8, 1.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--order", type=int, choices=(1, 2), default=2, help="element order")
    ap.add_argument("--edge", type=float, choices=(2.0, 1.5, 1.25, 1.0), default=2.0,
                    help="the scene's mesh (a bundled edge length, mm; default 2)")
    ap.add_argument("--tolerance", type=float, default=0.01,
                    help="marker tolerance choosing the refined pins, mm (default 0.01)")
    ap.add_argument("--max-pins", type=int, default=12,
                    help="refine around at most this many pins (the largest estimates; "
                    "default 12, to bound the refined mesh)")
    a = ap.parse_args()
    if not 0 < a.tolerance <= 1:
        ap.error(f"--tolerance {a.tolerance}: allowed (0, 1] mm")
    if not 1 <= a.max_pins <= 97:
        ap.error(f"--max-pins {a.max_pins}: allowed 1-97")

    import tactip_sim as ts
    from tactip_sim.fem.refinement.refine import PIN_EDGE_FRACTION, PIN_RADIUS_MM, carried_field
    from tactip_sim.geometry import build_pad
    from tactip_sim.mesh.local import Refinement, refined_mesh

    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={
        "element_order": a.order, "material_model": "neo_hookean", "mesh_edge_mm": a.edge})
    base = ts.Simulator(scene)
    base.warn_under_resolved = False
    roots = build_pad(scene).pins.roots
    print(f"P{a.order}, {a.edge:g} mm mesh ({len(base.mesh.tets)} tets); refined: edges "
          f"{PIN_EDGE_FRACTION * a.edge:.3g} mm within {PIN_RADIUS_MM:g} mm of the flagged pins")
    print(f"{'roll/pitch/depth':>17} {'pins':>5} {'tets':>7} {'coarse s':>9} {'cold s':>8} "
          f"{'its':>4} {'warm s':>8} {'its':>4} {'ratio':>6} {'markers apart mm':>17} "
          f"{'force rel':>10}")
    ratios = []
    for roll, pitch, depth in POSES:
        pose = ts.Pose(roll, pitch, depth)
        t0 = time.perf_counter()
        coarse = base.press(pose)
        t_coarse = time.perf_counter() - t0
        est = np.asarray(coarse.marker_errors_mm)
        pins = [int(p) for p in np.argsort(est)[::-1][:a.max_pins] if est[p] > a.tolerance]
        if not pins:
            print(f"{roll:6g}/{pitch:g}/{depth:g}: no pin above the tolerance, nothing refined")
            continue
        ref = Refinement(tuple(map(tuple, roots[pins])), PIN_EDGE_FRACTION * a.edge,
                         PIN_RADIUS_MM)
        sim = ts.Simulator(scene, mesh=refined_mesh(scene, ref, base=base.mesh))
        sim.warn_under_resolved = False
        sim.p1_guess = False  # "from rest": the load steps alone (a P2 press would else start
        # from the P1 answer, Simulator.p1_guess, since a3de65d)
        t0 = time.perf_counter()
        cold = sim.press(pose)
        t_cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        initial = carried_field(base.body.space, coarse.field_mm, sim.body.space)
        warm = sim.press(pose, initial=initial)
        t_warm = time.perf_counter() - t0  # the carrying included
        apart = float(np.linalg.norm(warm.markers_mm - cold.markers_mm, axis=1).max())
        ratios.append(t_cold / t_warm)
        label = f"{roll:g}/{pitch:g}/{depth:g}"
        print(f"{label:>17} {len(pins):5d} {len(sim.mesh.tets):7d} {t_coarse:9.1f} "
              f"{t_cold:8.1f} {cold.iterations:4d} {t_warm:8.1f} {warm.iterations:4d} "
              f"{t_cold / t_warm:6.2f} {apart:17.2e} {warm.force_N / cold.force_N - 1:10.1e}")
    if ratios:
        print(f"cold / warm: median {np.median(ratios):.2f}, range {min(ratios):.2f}-"
              f"{max(ratios):.2f} over {len(ratios)} poses")


if __name__ == "__main__":
    main()
