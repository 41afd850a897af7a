"""Coulomb friction and load paths: Cattaneo–Mindlin check, path dependence, cost.

Run:  python benchmarks/bench_friction.py [--edges 0.4 0.3 0.25] [--steps 10] [--chart PNG]

1. Cattaneo–Mindlin partial slip on ``scenes/hertz_block.toml`` (nu = 0.45, refined to each
   ``--edges`` size within 3 mm of the top centre, P2, reduced model): a 10 mm sphere pressed
   0.2 mm frictionless (a ~ 1.4 mm), then shifted sideways at mu = 0.5; per shift the measured
   ``Q / mu P``, stick radius ``c/a`` (outermost stuck over outermost contact node, and from
   the lumped areas of stuck and of all contact nodes) against ``(1 - Q/mu P)^(1/3)``, and
   the initial tangential stiffness against ``8 G* a``
   and against ``2 (1 - nu)/(2 - nu)`` times the measured normal stiffness.
2. Path dependence on ``scenes/shadow_fingertip.toml`` (reduced, P2): the plate re-oriented in
   contact from (0, 0) to (roll 8, pitch 0) at the training depth against a vertical tap to
   the same pose, largest marker difference for several mu.
3. Cost: a frictionless press against the friction load path (per step and per path).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def mindlin_table(edges, shifts):
    import tactip_sim as ts
    from tactip_sim.fem.contact.indenters import place
    from tactip_sim.fem.contact.lcp import solve_contact
    from tests.test_fem_friction import block_sim, centre, mindlin

    nu, radius, depth = 0.45, 10.0, 0.2
    g = 100.0 / (2 * (1 + nu))
    rows, curves = [], {}
    for edge in edges:
        t0 = time.perf_counter()
        sim = block_sim(edge, nu)
        sim.reduced  # noqa: B018
        build = time.perf_counter() - t0
        off = centre(sim)
        f = [abs(solve_contact(place(ts.Sphere(radius), ts.Pose(0, 0, d, offset_mm=off),
                                     sim._cand_rest), sim._cand_rest, sim.reduced
                               ).forces.sum(axis=0)[2]) for d in (depth - 0.005, depth + 0.005)]
        k_n = (f[1] - f[0]) / 0.01
        t0 = time.perf_counter()
        res = mindlin(sim, radius, depth, 0.5, [0.001, *shifts])
        solve = (time.perf_counter() - t0) / len(res)
        k_t = res[0, 4] / 0.001
        a_h = np.sqrt(radius * depth)
        errs = [(r, ca, ca / (1 - r) ** (1 / 3) - 1, cb / (1 - r) ** (1 / 3) - 1, share)
                for r, ca, cb, _, _, share in res[1:]]
        curves[edge] = errs
        rows.append((edge, len(sim._cand_rest), build, solve, errs,
                     k_t / (8 * g / (2 - nu) * a_h) - 1,
                     (k_t / k_n) / (2 * (1 - nu) / (2 - nu)) - 1,
                     k_n / (4 * g / (1 - nu) * a_h) - 1))
    return rows, curves


def path_table(mus, steps):
    import tactip_sim as ts

    scene = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    sim = ts.Simulator(scene)
    sim.reduced  # noqa: B018
    depth = scene.protocol.training_depth_mm
    end, start = ts.Pose(8, 0, depth), ts.Pose(0, 0, depth)
    plate = ts.Plate()
    out = []
    t0 = time.perf_counter()
    reps = 20
    for _ in range(reps):
        ref = sim.press(end, plate)
    t_press = (time.perf_counter() - t0) / reps
    for mu in mus:
        t0 = time.perf_counter()
        tap = sim.press_path(end, plate, steps=steps, friction=mu)[-1]
        t_tap = time.perf_counter() - t0
        t0 = time.perf_counter()
        turn = sim.press_path(end, plate, start=start, steps=steps, friction=mu)[-1]
        t_turn = time.perf_counter() - t0
        d = np.linalg.norm(turn.markers_mm - tap.markers_mm, axis=1)
        dref = np.linalg.norm(tap.markers_mm - ref.markers_mm, axis=1)
        out.append((mu, float(d.max()), float(d.mean()), float(dref.max()),
                    np.linalg.norm(turn.force_vector_N[:2]), t_tap / steps,
                    t_turn / (2 * steps)))
    return depth, t_press, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=float, nargs="+", default=[0.4, 0.3, 0.25])
    ap.add_argument("--shifts", type=float, nargs="+", default=[0.01, 0.02, 0.04, 0.06, 0.08])
    ap.add_argument("--mu", type=float, nargs="+", default=[0.0, 0.25, 0.5, 1.0])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--chart", default=None, help="write c/a against Q/muP as this PNG")
    ap.add_argument("--skip-mindlin", action="store_true")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    if not args.skip_mindlin:
        rows, curves = mindlin_table(args.edges, args.shifts)
        print("\n| refined edge (mm) | candidates | build (s) | s / step | c/a error at Q/muP: "
              "outermost nodes (lumped areas; normal-force share of slipping nodes inside c) "
              "| k_t vs 8G*a | k_t/k_n vs 2(1-nu)/(2-nu) | k_n vs Hertz 2E*a |")
        print("|---|---|---|---|---|---|---|---|")
        for e, n, b, s, errs, kt, ratio, kn in rows:
            ca = ", ".join(f"{r:.2f}: {100 * x:+.1f} % ({100 * y:+.1f} %; {100 * z:.1f} %)"
                           for r, _, x, y, z in errs)
            print(f"| {e:g} | {n} | {b:.1f} | {s:.2f} | {ca} | {100 * kt:+.1f} % "
                  f"| {100 * ratio:+.1f} % | {100 * kn:+.1f} % |")
        if args.chart:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            fig, ax = plt.subplots(figsize=(5, 4))
            r = np.linspace(0, 1, 200)
            ax.plot(r, (1 - r) ** (1 / 3), "k-", label="Cattaneo–Mindlin")
            for e, errs in curves.items():
                ax.plot([x[0] for x in errs], [x[1] for x in errs], "o", label=f"{e:g} mm")
            ax.set_xlabel("Q / μP")
            ax.set_ylabel("c / a")
            ax.legend()
            ax.set_title("Stick radius, sphere R 10 mm on block, μ 0.5")
            fig.tight_layout()
            fig.savefig(args.chart, dpi=120)
    depth, t_press, paths = path_table(args.mu, args.steps)
    print(f"\nfingertip, plate, re-orientation (0, 0) -> (8, 0) deg at {depth:g} mm vs vertical "
          f"tap, {args.steps} steps each; frictionless press {1000 * t_press:.1f} ms")
    print("| mu | max marker diff (mm) | mean (mm) | tap vs frictionless max (mm) "
          "| in-plane (x, y) force after turn (N) | tap ms/step | turn ms/step | step / press |")
    print("|---|---|---|---|---|---|---|---|")
    for mu, dmax, dmean, dref, ft, tt, tr in paths:
        print(f"| {mu:g} | {dmax:.3f} | {dmean:.3f} | {dref:.3f} | {ft:.3f} | {1000 * tt:.1f} "
              f"| {1000 * tr:.1f} | {tr / t_press:.1f} |")


if __name__ == "__main__":
    main()
