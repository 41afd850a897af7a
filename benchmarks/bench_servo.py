"""Real-time check of the grasp servo: simulated camera frames per second of wall time.

Run:  python benchmarks/bench_servo.py [--model MODEL.json] [--seconds 10] [--objects]

One finger against a plate at roll 10°, pitch -6°, servoed until the time-out (``--seconds``
of adjustment, as the paper's loop runs; default 10 s = 200 frames at 20 Hz after the closing
phase). Prints the per-stage milliseconds of a frame (FEM press, render with camera noise,
perception, controller) over all frames and over the adjustment frames alone (the joints move
every frame there, so every frame is a new press), the wall-clock loop rate and whether it
reaches the camera's 20 Hz. ``--objects`` adds the three-finger grasps (per finger-frame).

Without ``--model`` a 2nd-order regressor is fitted first, the calibration's way, on a
20-pose sweep of the nominal tip (as tests/test_servo.py does); its fitting is not timed.
The machine is shared: the load average before and after is printed with the numbers.
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
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))
STAGES = ("press_ms", "render_ms", "perceive_ms", "control_ms")


def small_model(scene, folder: Path) -> Path:
    from tactip_lab.fitting.fit import features, fit_model, save_model
    from tactip_lab.sampling.poses import PoseSet
    from tactip_lab.sampling.sweep import SweepSpec, run_sweep
    from tactip_sim.scene import scene_hash

    rr, pp = np.meshgrid([-14.0, -7.0, 0.0, 7.0, 14.0], [-10.0, -6.0, -2.0, 2.0],
                         indexing="ij")
    poses = np.stack([rr.ravel(), pp.ravel(), np.full(rr.size, 1.0)], axis=1)
    spec = SweepSpec(scene, "A", PoseSet("servo-train", poses), frames=2, nominal=True)
    res = run_sweep(spec, folder / "train", progress=False)
    path = folder / "model.json"
    save_model(fit_model(features(res.dataset), 2), path, feature="growth",
               fitted_on={"scene_hash": scene_hash(scene), "tip": "A"})
    return path


def report(label: str, fingers, wall_s: float, frames: int) -> None:
    from tactip_lab.servo.loop import TRACE_COLUMNS

    rows = np.concatenate([np.asarray(f.rows, float).reshape(-1, len(TRACE_COLUMNS))
                           for f in fingers])
    phases = np.concatenate([np.asarray(f.phases) for f in fingers])
    idx = {c: TRACE_COLUMNS.index(c) for c in STAGES}
    print(f"\n{label}: {frames} finger-frames in {wall_s:.2f} s wall -> "
          f"{frames / wall_s:.1f} simulated frames/s "
          f"({'meets' if frames / wall_s >= 20 else 'misses'} the camera's 20 Hz)")
    print("| frames | n | " + " | ".join(c.replace("_ms", "") for c in STAGES)
          + " | sum (ms) | rate from sum (Hz) |")
    print("|---|---:|" + "---:|" * (len(STAGES) + 2))
    for name, sel in (("all", np.ones(len(rows), bool)), ("adjust", phases == "adjust")):
        if not sel.any():
            continue
        means = [rows[sel, idx[c]].mean() for c in STAGES]
        print(f"| {name} | {sel.sum()} | " + " | ".join(f"{m:.2f}" for m in means)
              + f" | {sum(means):.1f} | {1e3 / sum(means):.1f} |")
    med = [np.median(rows[phases == "adjust", idx[c]]) if (phases == "adjust").any() else
           float("nan") for c in STAGES]
    print("| adjust, median | | " + " | ".join(f"{m:.2f}" for m in med)
          + f" | {sum(med):.1f} | {1e3 / sum(med):.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", help="a saved regressor of the scene (default: fit a small one)")
    ap.add_argument("--nominal", action="store_true",
                    help="the nominal tip (default: the model's manufactured tip; a fitted "
                    "small model is always nominal)")
    ap.add_argument("--seconds", type=float, default=10.0, help="adjustment time-out (10 s)")
    ap.add_argument("--objects", action="store_true", help="also time the three grasps")
    args = ap.parse_args()

    import tactip_sim as ts
    from tactip_lab.servo import ServoParams, load_servo_model, servo_chain
    from tactip_lab.servo.grasp import run_object, run_surface
    from tactip_lab.servo.grasp_objects import grasp

    print(f"load average before: {os.getloadavg()}")
    scene = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    with tempfile.TemporaryDirectory() as tmp:
        nominal = args.nominal
        if args.model is None:
            path, nominal = small_model(scene, Path(tmp)), True
        else:
            path = Path(args.model)
        model = load_servo_model(path, scene, nominal=nominal)
        t0 = time.perf_counter()
        chain = servo_chain(scene, model, nominal=nominal)
        chain.sim  # noqa: B018 - set-up, not timed below
        print(f"chain set-up {time.perf_counter() - t0:.2f} s (tip {model.tip}, "
              f"{'nominal' if nominal else 'manufactured'}; model {path.name})")
        # warm the renderer and perception's compiled kernels
        run_surface(chain, model, 4.0, -2.0, ServoParams(timeout_s=0.5), seed=99)
        params = ServoParams(timeout_s=args.seconds, stop_when_settled=False)
        t0 = time.perf_counter()
        res = run_surface(chain, model, 10.0, -6.0, params, seed=0)
        wall = time.perf_counter() - t0
        s = res.summaries[0]
        report("plate, roll 10°, pitch -6°, run to the time-out", res.fingers, wall,
               s["frames"])
        print(f"outcome {s['outcome']}, converged {s['converged']}, final error roll "
              f"{s['final_roll_error_deg']:+.2f}°, pitch {s['final_pitch_error_deg']:+.2f}°")
        if args.objects:
            for name in ("cube", "can", "bottle"):
                t0 = time.perf_counter()
                r = run_object(chain, model, grasp(name), ServoParams(), seed=0)
                wall = time.perf_counter() - t0
                report(f"{name}, three fingers (until settled)", r.fingers, wall,
                       sum(x["frames"] for x in r.summaries))
    print(f"\nload average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
