"""Mesh build time at several edge lengths, and the time to load a stored mesh and snap it.

Run:  python benchmarks/bench_mesh.py [SCENE]
Builds into a temporary cache, so the project cache is untouched. A build runs pytetwild in a
child process (its start and imports included); loading reads the stored mesher output and
snaps it onto the analytic surfaces, as every ``tetrahedralise`` does; the last line checks it
against a 1 s budget (a wall-clock figure, so measured here rather than asserted by a test).
Bundled meshes are ignored, so every edge length is built.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOAD_BUDGET_S = 1.0


def main() -> None:
    scene_path = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "scenes/shadow_fingertip.toml"
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["TACTIP_CACHE_DIR"] = tmp
        import tactip_sim as ts
        from tactip_sim.mesh import tetra

        tetra.BUNDLED_DIR = Path(tmp) / "no-bundle"  # build every edge length, bundled or not
        base = ts.load_scene(scene_path)
        print(f"scene {base.name}; cores: {os.cpu_count()}")
        print(f"{'edge mm':>8} {'nodes':>7} {'tets':>7} {'build s':>8} {'load+snap ms':>12} "
              f"{'min dihedral':>12} {'skin vol err %':>14}")
        worst = 0.0
        for edge in (3.0, 2.0, 1.5, 1.0):
            scene = ts.replace_in(base, fidelity={"mesh_edge_mm": edge})
            t0 = time.perf_counter()
            mesh = ts.tetrahedralise(scene)
            build = time.perf_counter() - t0
            t0 = time.perf_counter()
            again = ts.tetrahedralise(scene)
            load = time.perf_counter() - t0
            assert again.from_cache
            worst = max(worst, load)
            pad = ts.build_pad(scene)
            err = (100 * (mesh.region_volume(ts.REGION_SKIN) / pad.skin_volume_mm3 - 1)
                   if pad.outer is not None else float("nan"))
            print(f"{edge:8.1f} {len(mesh.nodes):7d} {len(mesh.tets):7d} {build:8.2f} "
                  f"{1e3 * load:12.2f} {mesh.quality.min_dihedral_deg:12.1f} {err:14.2f}")
        verdict = "within" if worst < LOAD_BUDGET_S else "OVER"
        print(f"slowest load+snap {1e3 * worst:.1f} ms: {verdict} the {LOAD_BUDGET_S:g} s budget")


if __name__ == "__main__":
    main()
