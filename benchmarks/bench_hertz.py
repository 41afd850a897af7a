"""Hertz on ``scenes/hertz_block.toml`` as shipped, with ``fidelity.contact_refinement = "auto"``:
spheres of random radius, depth and position (fixed seed) over the issue's ranges, each pressed
on the shipped 2.5 mm mesh (the error estimate before refinement and the error it really has)
and then as ``Simulator.press`` solves it with refinement (edge, tets, estimate, error, time).

Usage::

    python benchmarks/bench_hertz.py --out /tmp/bench_hertz            # 6 random + 3 named
    python benchmarks/bench_hertz.py --out /tmp/bench_hertz --cases 3  # fewer random cases

Expected values: Hertz's force at the sphere's apex depth below the flat top face (the pose's
depth counts from the first mesh node the sphere touches, so the apex goes slightly deeper than
asked between nodes), times the bonded-layer factor of
:func:`~tactip_sim.fem.contact.analytic.layer_factor` (h = 20 mm); the exact linear sphere solution
(Segedin) times the same factor is printed too, as Hertz's paraboloid is 2-6 % off for
a / R > 0.4. Each case is appended to ``OUT/cases.jsonl`` as it finishes (a rerun skips those
done); ``OUT/table.md`` is the table docs/fem.md shows. The machine's load is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tactip_sim as ts  # noqa: E402
from tactip_sim.fem.contact.analytic import hertz_force_mN, layer_factor, sphere_contact  # noqa: E402
from tactip_sim.fem.contact.indenters import place  # noqa: E402

E_KPA, NU, H_MM = 100.0, 0.3, 20.0  # scenes/hertz_block.toml
# the cases on the shipped mesh (sphere radius, contact radius), at the face's centre
NAMED = [(8.0, 1.1), (4.0, 0.6), (22.0, 0.66)]


def cases(n: int, seed: int) -> list[tuple[float, float, float, float]]:
    """(R, a, x, y): R log-uniform in [3, 30] mm, a uniform in [0.3, 2] mm, (x, y) uniform in
    the top face's central region |x|, |y| <= 10 mm."""
    rng = np.random.default_rng(seed)
    radius = np.exp(rng.uniform(np.log(3.0), np.log(30.0), n))
    a = rng.uniform(0.3, 2.0, n)
    xy = rng.uniform(-10.0, 10.0, (n, 2))
    out = [(float(r), float(c), float(x), float(y)) for r, c, (x, y) in zip(radius, a, xy,
                                                                             strict=True)]
    return out + [(r, c, 0.0, 0.0) for r, c in NAMED]


def expected(radius: float, apex_mm: float) -> tuple[float, float, float]:
    """Hertz × layer (mN), Segedin × layer (mN), Hertz contact radius (mm) at ``apex_mm``."""
    k = layer_factor(NU, radius, apex_mm, H_MM)
    seg, _ = sphere_contact(E_KPA, NU, radius, apex_mm)
    return hertz_force_mN(E_KPA, NU, radius, apex_mm) * k, seg * k, float(np.sqrt(radius * apex_mm))


def run_case(coarse: ts.Simulator, auto: ts.Simulator, radius: float, a: float, x: float,
             y: float) -> dict:
    depth = a * a / radius  # Hertz: a = sqrt(R d)
    pose = ts.Pose(0.0, 0.0, depth, offset_mm=(x, y))
    sphere = ts.Sphere(radius)
    row: dict = {"R_mm": radius, "a_mm": a, "x_mm": x, "y_mm": y, "depth_mm": depth}
    # on the shipped mesh: the estimate before refinement, and the real error
    t0 = time.perf_counter()
    st = coarse.press(pose, sphere)
    apex = H_MM - place(sphere, pose, coarse._cand_rest).origin_mm[2]
    hz, seg, _ = expected(radius, apex)
    row.update(coarse_estimate=st.error_estimate, coarse_error=st.force_N * 1e3 / hz - 1.0,
               coarse_s=time.perf_counter() - t0)
    from tactip_sim.fem.refinement.refine import plan

    p = plan(auto.body.space, auto.body.order, place(sphere, pose, auto._cand_rest),
             auto.scene, auto.scene.fidelity.contact_tolerance)
    row.update(predicted_a_mm=p.predicted.contact_radius_mm,
               predicted_estimate=p.predicted.error_estimate)
    # as Simulator.press solves it with refinement
    t0 = time.perf_counter()
    st = auto.press(pose, sphere)
    row["refined_s"] = time.perf_counter() - t0
    child = next(reversed(auto._refiner._children.values())) if auto._refiner else auto
    apex = H_MM - place(sphere, pose, child._cand_rest).origin_mm[2]
    hz, seg, a_hz = expected(radius, apex)
    a_fem = float(np.sqrt(st.contact_area_mm2 / np.pi))
    row.update(apex_mm=apex, refined_edge_mm=st.refined_edge_mm, tets=len(child.mesh.tets),
               estimate=st.error_estimate, force_mN=st.force_N * 1e3, hertz_mN=hz,
               segedin_mN=seg, error=st.force_N * 1e3 / hz - 1.0,
               error_segedin=st.force_N * 1e3 / seg - 1.0, a_fem_mm=a_fem, a_hertz_mm=a_hz,
               node_spacing_mm=st.node_spacing_mm, load=os.getloadavg()[0])
    # the same pose again (refined mesh and columns in memory)
    t0 = time.perf_counter()
    auto.press(pose, sphere)
    row["again_s"] = time.perf_counter() - t0
    return row


def table(rows: list[dict]) -> str:
    head = ("| R mm | a mm | x, y mm | est. on 2.5 mm mesh | error there | refined edge mm | "
            "tets | est. | error vs Hertz×layer | vs sphere×layer | a_FEM − a mm | "
            "first press s | again s |\n|" + "---|" * 13)
    lines = [head]
    for r in rows:
        lines.append(
            f"| {r['R_mm']:.1f} | {r['a_mm']:.2f} | {r['x_mm']:+.1f}, {r['y_mm']:+.1f} | "
            f"{100 * r['coarse_estimate']:.0f} % | {100 * r['coarse_error']:+.1f} % | "
            f"{r['refined_edge_mm']:.3g} | {r['tets']} | {100 * r['estimate']:.1f} % | "
            f"{100 * r['error']:+.2f} % | {100 * r['error_segedin']:+.2f} % | "
            f"{r['a_fem_mm'] - r['a_hertz_mm']:+.3f} | {r['refined_s']:.0f} | "
            f"{r['again_s']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for cases.jsonl, table.md")
    ap.add_argument("--cases", type=int, default=6, help="random cases (default 6)")
    ap.add_argument("--seed", type=int, default=16, help="seed of the random cases")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    done_path = args.out / "cases.jsonl"
    done = [json.loads(s) for s in done_path.read_text().splitlines()] if done_path.is_file() \
        else []
    scene = ts.load_scene(ROOT / "scenes" / "hertz_block.toml")
    coarse = ts.Simulator(ts.replace_in(scene, fidelity={"contact_refinement": "off"}),
                          solver="full")
    auto = ts.Simulator(scene, solver="full")
    if scene.fidelity.contact_refinement != "auto":
        print("note: the shipped scene has contact_refinement off; forcing auto", flush=True)
        auto = ts.Simulator(ts.replace_in(scene, fidelity={"contact_refinement": "auto"}),
                            solver="full")
    todo = cases(args.cases, args.seed)
    for i, (radius, a, x, y) in enumerate(todo):
        if any(abs(d["R_mm"] - radius) < 1e-12 and abs(d["a_mm"] - a) < 1e-12
               and abs(d["x_mm"] - x) < 1e-12 for d in done):
            continue
        row = run_case(coarse, auto, radius, a, x, y)
        done.append(row)
        with done_path.open("a") as fh:
            fh.write(json.dumps(row) + "\n")
        print(f"[{i + 1}/{len(todo)}] R={radius:.1f} a={a:.2f} at ({x:+.1f}, {y:+.1f}): coarse "
              f"est {100 * row['coarse_estimate']:.0f} % err {100 * row['coarse_error']:+.1f} %;"
              f" refined {row['refined_edge_mm']:.3g} mm, {row['tets']} tets, est "
              f"{100 * row['estimate']:.1f} %, err {100 * row['error']:+.2f} % (sphere "
              f"{100 * row['error_segedin']:+.2f} %), {row['refined_s']:.0f} s, again "
              f"{row['again_s']:.1f} s, load {row['load']:.1f}", flush=True)
    (args.out / "table.md").write_text(table(done))
    print(table(done))
    return 0


if __name__ == "__main__":
    sys.exit(main())
