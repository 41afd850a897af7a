"""End-to-end sweep speed (physics + render + perception), serial against 2 workers.

Run:  python benchmarks/bench_calibration.py [--poses 48] [--frames 8]
Sweeps the same random poses of the nominal tip into temporary folders, once in-process and once
on a 2-process Dask LocalCluster, and prints samples/s, perceived frames/s, the per-stage split of
one sample and the speed-up. Caches (mesh, compliance) are warmed first so only sweeping is timed.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--poses", type=int, default=48)
    ap.add_argument("--frames", type=int, default=8)
    args = ap.parse_args()

    import tactip_sim as ts
    from calibration.protocol import PoseSet
    from calibration.sweep import SweepSpec, TipWorker, run_sweep

    scene = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    p = scene.protocol
    rng = np.random.default_rng(5)
    poses = np.stack([rng.uniform(*p.roll_range_deg, args.poses),
                      rng.uniform(*p.pitch_range_deg, args.poses),
                      np.full(args.poses, p.training_depth_mm)], axis=1)
    spec = SweepSpec(scene, "A", PoseSet("bench", poses), frames=args.frames, nominal=True)

    # warm caches and time the stages of one sample in this process
    t0 = time.perf_counter()
    w = TipWorker(spec)
    setup = time.perf_counter() - t0
    stages = {"press": [], "render+truth": [], "noise": [], "perception": []}
    for pose in poses[:8]:
        a = time.perf_counter()
        st = w.sim.press(ts.Pose(*pose))
        b = time.perf_counter()
        rad = w.renderer.render_radiance(st.markers_mm, st.marker_directions, seed=1)
        w.renderer.ground_truth(st.markers_mm, st.marker_directions)
        c = time.perf_counter()
        imgs = w.renderer.camera.frames(rad, rng, args.frames)
        d = time.perf_counter()
        w.pipeline.reset()
        for im in imgs:
            w.pipeline.process(im)
        e = time.perf_counter()
        for k, v in zip(stages, (b - a, c - b, d - c, e - d), strict=True):
            stages[k].append(v)
    print(f"cores {os.cpu_count()}; worker set-up {setup:.2f} s; {args.frames} frames/sample")
    for k, v in stages.items():
        print(f"  {k:<13} {1e3 * np.median(v):7.1f} ms per sample (median of {len(v)})")

    rates = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, kw in (("serial", {"workers": 1}), ("2 workers", {"workers": 2})):
            t0 = time.perf_counter()
            res = run_sweep(spec, Path(tmp) / label.replace(" ", "_"), progress=False, chunk=4,
                            **kw)
            wall = time.perf_counter() - t0
            rates[label] = res.computed / wall
            print(f"{label:>10}: {res.computed} samples in {wall:6.1f} s = "
                  f"{rates[label]:5.2f} samples/s = {rates[label] * args.frames:6.1f} frames/s "
                  f"(including worker start-up)")
    print(f"speed-up 1 -> 2 workers: {rates['2 workers'] / rates['serial']:.2f}x")


if __name__ == "__main__":
    main()
