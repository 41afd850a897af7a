"""Distinct poses per second, end to end, with the Mitsuba and the raster cap layer (issue 21).

    python benchmarks/bench_speed.py [--poses 40] [--skip-hd] [--json out.json]

One sample = FEM press of a new pose + render (radiance, ground truth, camera model) +
perception of one frame: ``tactip_lab.sampling.chain.Chain.sample`` with ``frames=1``, nominal tip
A,
the default scene at 640x480 and at the hardware's 1920x1080 (pixel pitch divided by 3, so the
optics are the same). The two cap layers run the same random poses interleaved pose by pose
(load from other processes falls on both alike), each chain pressing its own poses. The first
few poses warm caches and compiled code and are not timed. Prints per-stage medians, poses per
second (1 / mean time per pose) and the ratio, and the load average before and after.
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
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

WARM = 3


def scenes(skip_hd: bool) -> dict[str, object]:
    import tactip_sim as ts

    base = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    out = {"640x480": base}
    if not skip_hd:
        pitch = base.camera.pixel_pitch_um
        out["1920x1080"] = ts.replace_in(base, camera={"resolution": [1920, 1080],
                                                       "pixel_pitch_um": pitch / 3})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=40, help="timed poses per resolution")
    ap.add_argument("--skip-hd", action="store_true", help="640x480 only")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()

    import tactip_sim as ts
    from tactip_lab.sampling.chain import Chain, set_tag

    print(f"load average before: {os.getloadavg()}; cores {os.cpu_count()}")
    results: dict[str, dict] = {}
    for res_name, scene in scenes(args.skip_hd).items():
        p = scene.protocol
        rng = np.random.default_rng(21)
        n = args.poses + WARM
        poses = np.stack([rng.uniform(*p.roll_range_deg, n), rng.uniform(*p.pitch_range_deg, n),
                          np.full(n, p.training_depth_mm)], axis=1)
        chains = {}
        for layer in ("mitsuba", "raster"):
            s = ts.replace_in(scene, imaging={"cap_layer": layer})
            t0 = time.perf_counter()
            chains[layer] = Chain.for_tip(s, "A", nominal=True, frames=1)
            chains[layer].sim  # noqa: B018 - the FEM precompute belongs to the set-up
            print(f"{res_name} {layer}: set-up {time.perf_counter() - t0:.1f} s")
        per: dict[str, dict[str, list[float]]] = {
            k: {"physics": [], "render": [], "perception": [], "total": []} for k in chains}
        tag = set_tag("bench_speed")
        for i, pose in enumerate(poses):
            for layer, ch in chains.items():
                t0 = time.perf_counter()
                s = ch.sample(pose, tag, i)
                total = time.perf_counter() - t0
                if i >= WARM:
                    for k, v in s.seconds.items():
                        per[layer][k].append(v)
                    per[layer]["total"].append(total)
        out = {}
        for layer, st in per.items():
            rate = 1.0 / float(np.mean(st["total"]))
            out[layer] = {k: 1e3 * float(np.median(v)) for k, v in st.items()}
            out[layer]["poses_per_s"] = rate
            print(f"{res_name} {layer:8s}: " + ", ".join(
                f"{k} {out[layer][k]:.1f} ms" for k in ("physics", "render", "perception",
                                                          "total"))
                  + f" (medians); {rate:.1f} poses/s (mean over {len(st['total'])})")
        ratio = out["raster"]["poses_per_s"] / out["mitsuba"]["poses_per_s"]
        rratio = out["mitsuba"]["render"] / out["raster"]["render"]
        print(f"{res_name}: raster / mitsuba = {ratio:.2f}x poses/s; render stage "
              f"{rratio:.2f}x faster")
        out["ratio_poses_per_s"] = ratio
        out["ratio_render"] = rratio
        results[res_name] = out
    print(f"load average after: {os.getloadavg()}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
