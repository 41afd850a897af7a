"""End-to-end sweep speed (physics + render + perception), serial against 2 workers.

Run:  python benchmarks/bench_calibration.py [--poses 48] [--frames 60]
Sweeps the same random poses of the nominal tip into temporary folders, once in-process and once
on a 2-process Dask LocalCluster, and prints the per-stage split of one sample, each run's
start-up (cluster, and in every process the tip's set-up: simulator, renderer compile, rest
frame) and its steady rate in perceived frames/s, and the speed-up with and without start-up.
Caches (mesh, compliance) are warmed first so only sweeping is timed.
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
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()

    import tactip_sim as ts
    from tactip_lab.sampling.executor import close_client, open_client
    from tactip_lab.sampling.poses import PoseSet
    from tactip_lab.sampling.sweep import SweepSpec, run_sweep, warm_up

    scene = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    p = scene.protocol
    rng = np.random.default_rng(5)
    poses = np.stack([rng.uniform(*p.roll_range_deg, args.poses),
                      rng.uniform(*p.pitch_range_deg, args.poses),
                      np.full(args.poses, p.training_depth_mm)], axis=1)
    spec = SweepSpec(scene, "A", PoseSet("bench", poses), frames=args.frames, nominal=True)

    # warm caches and time the stages of one sample in this process
    t0 = time.perf_counter()
    w = spec.with_mesh().chain()
    w.sim  # noqa: B018 - the simulator and its compliance, part of the set-up
    setup = time.perf_counter() - t0
    stages = {"press": [], "render+truth": [], "noise": [], "perception": []}
    for pose in poses[:8]:
        a = time.perf_counter()
        st, _ = w.press(pose)
        b = time.perf_counter()
        rad = w.radiance(st, rng)
        w.truth(st)
        c = time.perf_counter()
        imgs = w.renderer.imaging.frames(rad, rng, args.frames)
        d = time.perf_counter()
        w.perceive(imgs)
        e = time.perf_counter()
        for k, v in zip(stages, (b - a, c - b, d - c, e - d), strict=True):
            stages[k].append(v)
    print(f"cores {os.cpu_count()}; worker set-up {setup:.2f} s; {args.frames} frames/sample")
    for k, v in stages.items():
        print(f"  {k:<13} {1e3 * np.median(v):7.1f} ms per sample (median of {len(v)})")

    steady, total = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, workers in (("serial", 1), ("2 workers", 2)):
            t0 = time.perf_counter()
            client = open_client(workers, None)
            setups = warm_up(spec, client)  # per process: build the tip, compile, rest frame
            t1 = time.perf_counter()
            res = run_sweep(spec, Path(tmp) / label.replace(" ", "_"), progress=False, chunk=4,
                            client=client)
            t2 = time.perf_counter()
            close_client(client)
            steady[label] = res.computed / (t2 - t1)
            total[label] = res.computed / (t2 - t0)
            print(f"{label:>10}: start-up {t1 - t0:5.1f} s (worker set-up "
                  f"{', '.join(f'{v:.1f}' for v in setups)} s), then {res.computed} samples in "
                  f"{t2 - t1:6.1f} s = {steady[label] * args.frames:6.1f} frames/s "
                  f"({total[label] * args.frames:6.1f} with start-up); in-worker "
                  f"{1e3 * res.sample_seconds / res.computed:.0f} ms per sample")
    print(f"speed-up 1 -> 2 workers: {steady['2 workers'] / steady['serial']:.2f}x steady, "
          f"{total['2 workers'] / total['serial']:.2f}x including start-up")


if __name__ == "__main__":
    main()
