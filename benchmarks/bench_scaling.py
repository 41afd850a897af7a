"""Sweep cost against sweep size, and against the number of Dask worker processes.

Run:  python benchmarks/bench_scaling.py [--small 50] [--large 5000] [--workers 1,2,3,4]
                                         [--scaling-poses 2000] [--frames 1] [--cap-layer raster]

Issue 21 asks that the cost per sample stay flat with the sweep's size (50 against 5 000
samples within 10 %) and that adding workers pay (1 -> 2 workers >= 1.8x; a local cluster of N
processes measured). Everything goes through ``tactip_lab.sampling.sweep.run_sweep`` into temporary
dataset folders: the press, the render, the camera noise, the perception and the files written
per sample (a PNG and a record), and the tables written when a sweep completes.

1. **Size.** In this process (no cluster), after a warm-up sweep: sweeps of ``--small``
   samples, one of ``--large``, then ``--small`` ones again (so a drift of the machine's load
   shows as a difference between the small sweeps before and after). Wall time per sample,
   including the final tables.
2. **Workers.** The same ``--scaling-poses`` sweep on a Dask ``LocalCluster`` of 1, 2, 3, ...
   single-threaded processes (``tactip_lab.sampling.executor.open_client``). Each cluster's start-up
   and every worker's chain set-up (``warm_up``) are timed apart from the sweep; the speed-up is
   of the steady sweep against the 1-process cluster's.

The default level is the cheapest of the fidelity study (raster caps, one frame per sample:
docs/speed.md), where per-sample overheads (files, scheduling) weigh the most; ``--frames 60
--cap-layer mitsuba`` measures the README's main job's level. Poses: the default scene's
roll/pitch ranges at its training depth, seeded. Caches (mesh, compliance, raster maps) are
filled by the warm-up. BENCHMARKS.md, "Scaling", records a run.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _poses(scene, n: int, seed: int) -> np.ndarray:
    p = scene.protocol
    rng = np.random.default_rng([seed, n])
    return np.stack([rng.uniform(*p.roll_range_deg, n), rng.uniform(*p.pitch_range_deg, n),
                     np.full(n, p.training_depth_mm)], axis=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small", type=int, default=50, help="samples of the small sweeps")
    ap.add_argument("--repeats", type=int, default=3,
                    help="small sweeps before and after the large one (default 3 each)")
    ap.add_argument("--large", type=int, default=5000, help="samples of the large sweep")
    ap.add_argument("--workers", default="1,2,3,4", help="cluster sizes, comma-separated")
    ap.add_argument("--scaling-poses", type=int, default=2000,
                    help="samples of each cluster's sweep (default 2000: at the cheap level "
                         "600 samples take 7-12 s, and the ratio moved by 10 %% between runs)")
    ap.add_argument("--frames", type=int, default=1, help="noisy frames per sample (default 1)")
    ap.add_argument("--cap-layer", default="raster", choices=("raster", "mitsuba"),
                    help="imaging.cap_layer (default raster)")
    ap.add_argument("--chunk", type=int, default=8,
                    help="samples per Dask task (run_sweep's chunk, default 8)")
    ap.add_argument("--skip-size", action="store_true", help="only the worker scaling")
    ap.add_argument("--skip-workers", action="store_true", help="only the size test")
    args = ap.parse_args(argv)
    workers = [int(w) for w in args.workers.split(",") if w.strip()]
    if min(args.small, args.large, args.scaling_poses, args.frames, args.chunk, *workers) < 1:
        ap.error("--small, --large, --scaling-poses, --frames, --chunk and --workers must be "
                 ">= 1")

    import tactip_sim as ts
    from tactip_lab.sampling.executor import close_client, open_client
    from tactip_lab.sampling.poses import PoseSet
    from tactip_lab.sampling.sweep import SweepSpec, run_sweep, warm_up

    scene = ts.replace_in(ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml"),
                          imaging={"cap_layer": args.cap_layer})

    def spec(name: str, n: int, seed: int) -> SweepSpec:
        return SweepSpec(scene, "A", PoseSet(name, _poses(scene, n, seed)),
                         frames=args.frames, nominal=True).with_mesh()

    print(f"level: cap_layer={args.cap_layer}, {args.frames} frame(s) per sample; "
          f"{os.cpu_count()} cores; load average at start "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_scaling_") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        warm = spec("warm", 16, 99)
        warm_up(warm)
        run_sweep(warm, tmp / "warm", progress=False)
        print(f"warm-up (chain set-up and 16 samples): {time.perf_counter() - t0:.1f} s",
              flush=True)

        if not args.skip_size:
            print("\n| sweep | samples | wall (s) | per sample (ms) |\n|---|---:|---:|---:|")
            per = {"before": [], "large": [], "after": []}

            def timed(label: str, n: int, seed: int) -> None:
                s = spec(f"size{n}_{seed}", n, seed)
                t = time.perf_counter()
                run_sweep(s, tmp / f"size_{label}_{seed}", progress=False)
                wall = time.perf_counter() - t
                per[label].append(wall / n)
                print(f"| {label} | {n} | {wall:.2f} | {1e3 * wall / n:.2f} |", flush=True)

            for k in range(args.repeats):
                timed("before", args.small, k)
            timed("large", args.large, 1000)
            for k in range(args.repeats):
                timed("after", args.small, 100 + k)
            small = np.median(per["before"] + per["after"])
            print(f"\nper sample: small sweeps (median of {2 * args.repeats}) "
                  f"{1e3 * small:.2f} ms, large {1e3 * per['large'][0]:.2f} ms: "
                  f"large / small = {per['large'][0] / small:.3f}; small before / after = "
                  f"{np.median(per['before']) / np.median(per['after']):.3f}", flush=True)

        if not args.skip_workers:
            print(f"\nchunk {args.chunk}\n| workers | cluster start (s) | set-up per worker (s) | "
                  "sweep (s) | samples/s | speed-up vs 1 | in-worker time per sample (ms) | "
                  "client CPU (% of a core) |\n|---:|---:|---:|---:|---:|---:|---:|---:|")
            base = None
            for n in workers:
                t = time.perf_counter()
                # a 1-process cluster too: every size takes the same scheduling path
                client = open_client(n, None, cluster_of_one=True)
                start = time.perf_counter() - t
                s = spec("scale", args.scaling_poses, 7)
                setup = warm_up(s, client)
                t, cpu = time.perf_counter(), time.process_time()
                res = run_sweep(s, tmp / f"workers{n}", client=client, progress=False,
                                chunk=args.chunk)
                wall = time.perf_counter() - t
                cpu = time.process_time() - cpu
                close_client(client)
                rate = args.scaling_poses / wall
                base = rate if base is None else base
                print(f"| {n} | {start:.1f} | {np.mean(setup):.1f} | {wall:.1f} | {rate:.1f} | "
                      f"{rate / base:.2f}x | {1e3 * res.sample_seconds / res.computed:.1f} | "
                      f"{100 * cpu / wall:.0f} |",
                      flush=True)
    print(f"\nload average at end {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
