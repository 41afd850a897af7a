"""Benchmark of the FEM contact solver: precompute, per-pose time of the reduced, full and
neo-Hookean solvers, and peak memory, on the fingertip scene.

Usage::

    python benchmarks/bench_fem.py                 # P2 (default fidelity) and P1
    python benchmarks/bench_fem.py --orders 1      # quick: P1 only
    python benchmarks/bench_fem.py --poses 855     # reduced solver on the full protocol size
    python benchmarks/bench_fem.py --validate      # Hertz sweep and mesh convergence numbers

Prints one table per element order; ratios are within one run (the machine is shared, so
absolute times drift between runs). The compliance is recomputed (``use_cache=False``), then
its cached load is timed separately.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

import tactip_sim as ts
from tactip_sim.fem.elasticity import cholmod_available, cholmod_blas_is_reference

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "shadow_fingertip.toml"


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def protocol_poses(scene, n: int) -> list[ts.Pose]:
    """The training grid at the training depth, then random test poses at depth offsets."""
    p = scene.protocol
    rolls = np.arange(p.roll_range_deg[0], p.roll_range_deg[1] + 1e-9, p.roll_step_deg)
    pitches = np.arange(p.pitch_range_deg[0], p.pitch_range_deg[1] + 1e-9, p.pitch_step_deg)
    poses = [ts.Pose(r, q, p.training_depth_mm) for r in rolls for q in pitches]
    rng = np.random.default_rng(p.seed)
    while len(poses) < n:
        for off in p.test_depth_offsets_mm:
            poses.append(ts.Pose(rng.uniform(*p.roll_range_deg), rng.uniform(*p.pitch_range_deg),
                                 p.training_depth_mm + off))
    return poses[:n]


def bench(order: int, n_poses: int, n_full: int, n_nh: int) -> dict[str, float]:
    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={"element_order": order})
    out: dict[str, float] = {}
    mesh = ts.tetrahedralise(scene)  # cached mesh: meshing is not the FEM's cost
    t0 = time.perf_counter()
    sim = ts.Simulator(scene, mesh=mesh, use_cache=False)
    out["setup (snap, space, markers) s"] = time.perf_counter() - t0
    space = sim.body.space
    out["dofs"] = space.n_dofs
    out["candidate nodes"] = len(space.candidates)
    t0 = time.perf_counter()
    sim.body.stiffness  # noqa: B018
    out["assemble s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim.reduced  # noqa: B018
    out["compliance precompute s"] = time.perf_counter() - t0
    out["peak RSS after precompute MB"] = rss_mb()
    with tempfile.TemporaryDirectory() as tmp:  # time a cached load of the same compliance
        from tactip_sim import cache
        from tactip_sim.fem.reduced import ReducedModel

        os.environ["TACTIP_CACHE_DIR"] = tmp
        red, body = sim.reduced, sim.body
        cache.save_npz(cache.path_for("compliance", body.key, ".npz"),
                       compliance=red.compliance)
        cache.save_npz(cache.path_for("marker_response", body.markers_key, ".npz"),
                       response=red.marker_response_t.T)
        cache.save_npz(cache.path_for("compliance", body.key + "-bounds", ".npz"),
                       clusters=red.clusters, bound=red.cluster_bound)
        t0 = time.perf_counter()
        ReducedModel(body)
        out["compliance cached load s"] = time.perf_counter() - t0
        del os.environ["TACTIP_CACHE_DIR"]
    poses = protocol_poses(scene, n_poses)
    sim.press(poses[0])  # warm the pages of the compliance
    t0 = time.perf_counter()
    states = sim.press_many(poses)
    dt = time.perf_counter() - t0
    out["reduced ms/pose"] = 1000 * dt / len(poses)
    out["reduced poses"] = len(poses)
    out["reduced max iterations"] = max(s.iterations for s in states)
    out["reduced mean contact nodes"] = float(np.mean([len(s.contact_nodes) for s in states]))
    out["max |penetration| mm"] = max(s.max_penetration_mm for s in states)
    out["max complementarity mN mm"] = max(s.complementarity for s in states)
    t0 = time.perf_counter()
    sim.body.factor  # noqa: B018
    out["factorise s"] = time.perf_counter() - t0
    diffs, t_full = [], []
    for pose in poses[: max(n_full, 0)]:
        t0 = time.perf_counter()
        full = sim.press(pose, solver="full")
        t_full.append(time.perf_counter() - t0)
        diffs.append(np.abs(full.markers_mm - sim.press(pose).markers_mm).max())
    if t_full:
        out["full s/pose"] = float(np.mean(t_full))
        out["full vs reduced max marker diff mm"] = float(max(diffs))
    t_nh = []
    for pose in poses[: max(n_nh, 0)]:
        t0 = time.perf_counter()
        nh = sim.press(pose, solver="neo_hookean")
        t_nh.append(time.perf_counter() - t0)
        lin = sim.press(pose)
        out["neo-Hookean Newton iterations"] = nh.iterations
        out["neo-Hookean vs linear marker RMS diff %"] = 100 * float(
            np.linalg.norm(nh.marker_displacements_mm - lin.marker_displacements_mm)
            / np.linalg.norm(lin.marker_displacements_mm))
    if t_nh:
        out["neo-Hookean s/pose"] = float(np.mean(t_nh))
    out["peak RSS MB"] = rss_mb()
    if t_full:
        out["ratio full/reduced"] = out["full s/pose"] / (out["reduced ms/pose"] / 1000)
    if t_nh:
        out["ratio neo-Hookean/reduced"] = out["neo-Hookean s/pose"] / (out["reduced ms/pose"]
                                                                        / 1000)
    return out


def validate() -> None:
    """Print the Hertz sweep (both Poisson ratios) and the mesh-convergence study."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_fem_convergence import solve
    from test_fem_hertz import make_sim, press_sphere

    from tactip_sim.fem.analytic import hertz_force_mN, layer_factor

    print("\nHertz: sphere on scenes/hertz_block.toml (E = 100 kPa), P2, full solver")
    print(f"  {'nu':>5} {'R mm':>5} {'d mm':>7} {'a mm':>6} {'F mN':>9} {'F/Hertz-1':>10} "
          f"{'F/layer-1':>10} {'a_area/a-1':>10}")
    for nu in (0.3, 0.45):
        sim = make_sim(nu)
        for radius in (2.5, 5.0, 10.0):
            depths = np.array([0.5, 0.75, 1.0]) ** 2 / radius
            force = []
            for d in depths:
                st = press_sphere(sim, radius, d)
                f = st.force_N * 1000
                force.append(f)
                h = hertz_force_mN(100.0, nu, radius, d)
                a = np.sqrt(radius * d)
                print(f"  {nu:5.2f} {radius:5.1f} {d:7.4f} {a:6.3f} {f:9.4f} {f / h - 1:+10.4f} "
                      f"{f / h / layer_factor(nu, radius, d) - 1:+10.4f} "
                      f"{np.sqrt(st.contact_area_mm2 / np.pi) / a - 1:+10.4f}")
            slope = np.polyfit(np.log(depths), np.log(force), 1)[0]
            print(f"  {nu:5.2f} {radius:5.1f}  fitted exponent {slope:.4f}")
    print("\nMesh convergence: plate at roll 4, pitch -2, depth 1 mm, full solver;")
    print("  marker-displacement error relative to P2 on the 1.5 mm mesh")
    ref = solve(1.5, 2)
    r = ref.marker_displacements_mm
    for order in (1, 2):
        sizes, errs = [], []
        for h in (3.0, 2.5, 2.0):
            st = solve(h, order)
            e = np.linalg.norm(st.marker_displacements_mm - r) / np.linalg.norm(r)
            sizes.append(h)
            errs.append(e)
            print(f"  P{order} h={h:.1f} mm  force {st.force_N:.4f} N  marker error {e:.4f}")
        rate = np.polyfit(np.log(sizes), np.log(errs), 1)[0]
        print(f"  P{order} observed rate {rate:.2f}")
    print(f"  reference P2 h=1.5 mm force {ref.force_N:.4f} N")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", type=int, nargs="+", default=[2, 1])
    ap.add_argument("--poses", type=int, default=255, help="reduced-solver poses (protocol)")
    ap.add_argument("--full", type=int, default=2, help="poses for the full solver")
    ap.add_argument("--nh", type=int, default=1, help="poses for the neo-Hookean solver")
    ap.add_argument("--validate", action="store_true",
                    help="print the Hertz and mesh-convergence validation numbers instead")
    args = ap.parse_args()
    print(f"date {datetime.date.today()}, {platform.machine()} {os.cpu_count()} cores, "
          f"python {platform.python_version()}, CHOLMOD {cholmod_available()}, "
          f"CHOLMOD BLAS reference (netlib): {cholmod_blas_is_reference()}")
    if args.validate:
        validate()
        return
    for order in args.orders:
        res = bench(order, args.poses, args.full, args.nh)
        print(f"\nP{order} on the default 2 mm mesh")
        for k, v in res.items():
            print(f"  {k:40s} {v:.4g}" if isinstance(v, float) else f"  {k:40s} {v}")


if __name__ == "__main__":
    main()
