"""Mesh build time at several edge lengths, and the cache load time.

Run:  python benchmarks/bench_mesh.py [SCENE]
Builds into a temporary cache, so the project cache is untouched.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    scene_path = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "scenes/shadow_fingertip.toml"
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["TACTIP_CACHE_DIR"] = tmp
        import tactip_sim as ts

        base = ts.load_scene(scene_path)
        print(f"scene {base.name}; cores: {os.cpu_count()}")
        print(f"{'edge mm':>8} {'nodes':>7} {'tets':>7} {'build s':>8} {'load ms':>8} "
              f"{'min dihedral':>12} {'skin vol err %':>14}")
        for edge in (3.0, 2.0, 1.5, 1.0):
            scene = ts.replace_in(base, fidelity={"mesh_edge_mm": edge})
            t0 = time.perf_counter()
            mesh = ts.tetrahedralise(scene)
            build = time.perf_counter() - t0
            t0 = time.perf_counter()
            again = ts.tetrahedralise(scene)
            load = time.perf_counter() - t0
            assert again.from_cache
            pad = ts.build_pad(scene)
            err = 100 * (mesh.region_volume(ts.REGION_SKIN) / pad.skin_volume_mm3 - 1)
            print(f"{edge:8.1f} {len(mesh.nodes):7d} {len(mesh.tets):7d} {build:8.2f} "
                  f"{1e3 * load:8.2f} {mesh.quality.min_dihedral_deg:12.1f} {err:14.2f}")


if __name__ == "__main__":
    main()
