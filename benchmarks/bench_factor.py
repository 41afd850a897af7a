"""What the neo-Hookean reference's sparse Cholesky factorisation costs, and what two BLAS
threads buy: the P2 tangent of the default pad at rest, on the bundled meshes, factorised by
CHOLMOD (METIS ordering, supernodal; the symbolic analysis done once, as in a press) with one
and with two BLAS threads (``TACTIP_FACTOR_THREADS``, docs/fem.md), alternated in one process.
Prints each size's dofs, the factor's nonzeros and the memory it takes (resident growth while
one factor is alive), the median time per factorisation with one and two threads and their
ratio; the fitted growth of time and nonzeros with the dofs.

Usage::

    python benchmarks/bench_factor.py                       # 2, 1.25 and 1 mm, 3 rounds
    python benchmarks/bench_factor.py --edges 2 --rounds 5

Two threads pay only on an otherwise idle machine: run it alone.
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"


def _resident_gb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1e6
    return float("nan")


def measure(edge: float, rounds: int) -> dict:
    import tactip_sim as ts
    from tactip_sim.fem.neohookean.solver import NeoHookeanBody, _pattern
    from tactip_sim.fem.tolerances import single_threaded_blas

    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={
        "mesh_edge_mm": edge, "element_order": 2, "material_model": "neo_hookean"})
    body = ts.Simulator(scene).body
    nh = NeoHookeanBody(body)
    pattern = _pattern(nh)
    blocks = pattern.assemble(nh.residual(np.zeros(body.space.n_dofs), tangent=True)[1])
    fixed = np.ones(body.space.n_dofs, dtype=bool)
    fixed[body.free] = False
    fixed = fixed.reshape(-1, 3)
    times: dict[int, list[float]] = {1: [], 2: []}
    with single_threaded_blas():
        pattern.factor(blocks, fixed)  # the symbolic analysis, kept on the pattern
        gc.collect()
        before = _resident_gb()
        solve = pattern.factor(blocks, fixed)
        held_gb = _resident_gb() - before
        nnz = solve.L().nnz
        del solve
        for _ in range(rounds):
            for threads in (1, 2):
                os.environ["TACTIP_FACTOR_THREADS"] = str(threads)
                t0 = time.perf_counter()
                solve = pattern.factor(blocks, fixed)
                times[threads].append(time.perf_counter() - t0)
                del solve
    os.environ.pop("TACTIP_FACTOR_THREADS", None)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    return {"edge": edge, "tets": len(body.space.elements), "dofs": body.space.n_dofs,
            "nnz": nnz, "factor_gb": held_gb, "one": one, "two": two}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=float, nargs="+", default=[2.0, 1.25, 1.0],
                    help="bundled mesh sizes (mm; default 2 1.25 1)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="factorisations per thread count, alternated (default 3)")
    a = ap.parse_args()
    if a.rounds < 1:
        ap.error("--rounds must be at least 1")
    if (os.cpu_count() or 1) < 2:
        ap.error("two BLAS threads need two CPUs")
    rows = [measure(e, a.rounds) for e in a.edges]
    print(f"{'edge mm':>8} {'tets':>7} {'dofs':>8} {'nnz(L)':>12} {'factor GB':>9} "
          f"{'1 thread s':>10} {'2 threads s':>11} {'ratio':>6}")
    for r in rows:
        print(f"{r['edge']:>8g} {r['tets']:>7} {r['dofs']:>8} {r['nnz']:>12} "
              f"{r['factor_gb']:>9.2f} {r['one']:>10.2f} {r['two']:>11.2f} "
              f"{r['one'] / r['two']:>6.2f}")
    if len(rows) >= 2:
        dofs = np.log([r["dofs"] for r in rows])
        for key, name in (("nnz", "nnz(L)"), ("one", "one-thread time")):
            slope = np.polyfit(dofs, np.log([r[key] for r in rows]), 1)[0]
            print(f"{name} grows as dofs^{slope:.2f}")


if __name__ == "__main__":
    main()
