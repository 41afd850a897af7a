"""Time the perception stages per 640x480 frame.

    python benchmarks/bench_perception.py [--repeats 50] [--threads N] [--real ../shared/real]

Prints the median (and 10th/90th percentile) milliseconds per frame of detect, track,
Voronoi, CoP and their total (the four back to back, timed as one unit, not summed), plus
``FeaturePipeline.process`` (which adds grey conversion, both CoP variants and contact), on a
synthetic ~97-marker frame and on the real 331-pin rest frame. The stages take turns in every
repeat, so load from other processes falls on all of them alike. Detection is timed with the
marker size estimated from the frame and with the size measured on the rest frame (what
``FeaturePipeline`` does for every frame after the rest frame; the total uses the latter).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402

import perception as pc  # noqa: E402
from perception.synthetic import render_markers  # noqa: E402


def _time_round_robin(stages: dict, repeats: int, warmup: int = 3) -> dict[str, np.ndarray]:
    """ms per call of every stage; the stages take turns, so load from other processes on a
    shared machine falls on all of them alike instead of on whichever ran at the wrong time."""
    for fn in stages.values():
        for _ in range(warmup):
            fn()
    out = {name: np.empty(repeats) for name in stages}
    for i in range(repeats):
        for name, fn in stages.items():
            t0 = time.perf_counter()
            fn()
            out[name][i] = (time.perf_counter() - t0) * 1e3
    return out


def _frames_synthetic():
    centre = np.array([319.5, 239.5])
    rest = pc.hex_lattice(97, 36.0, centre)
    press = centre + (60.0, -40.0)
    d = rest - press
    pressed = rest + 0.35 * d * np.exp(-(d**2).sum(axis=1, keepdims=True) / (2 * 50.0**2))
    opts = dict(diameter_px=10.0, noise_sigma=0.02, blur_sigma_px=1.0, illumination=0.3,
                n_glints=6)
    return (render_markers(rest, rng=0, **opts).image,
            render_markers(pressed, rng=1, **opts).image)


def bench(name: str, rest_image: np.ndarray, image: np.ndarray, expected: int,
          repeats: int) -> list[str]:
    pipe = pc.FeaturePipeline(rest_image, expected_count=expected)
    region = pipe.region
    diameter = pipe.expected_diameter_px  # measured on the rest frame, as the pipeline does
    tracker = pc.MarkerTracker(pipe.rest_points)
    det = pc.detect_markers_detailed(image, expected_count=expected,
                                     expected_diameter_px=diameter)
    tracked = tracker.update(det.points)
    areas = pc.voronoi_areas(tracked, region)

    def track():
        tracker.reset()
        tracker.update(det.points)

    def total():
        d = pc.detect_markers_detailed(image, expected_count=expected,
                                       expected_diameter_px=diameter)
        tracker.reset()
        p = tracker.update(d.points)
        a = pc.voronoi_areas(p, region)
        pc.centre_of_pressure(p, a)

    def process():
        pipe.reset()
        pipe.process(image)

    stages = {
        "detect (marker size estimated)":
            lambda: pc.detect_markers_detailed(image, expected_count=expected),
        "detect (size from the rest frame)":
            lambda: pc.detect_markers_detailed(image, expected_count=expected,
                                               expected_diameter_px=diameter),
        "track": track,
        "voronoi": lambda: pc.voronoi_areas(tracked, region),
        "cop": lambda: pc.centre_of_pressure(tracked, areas),
        "total (detect+track+voronoi+cop)": total,
        "FeaturePipeline.process": process,
    }
    lines = [f"{name}: {image.shape[1]}x{image.shape[0]}, {det.count} markers detected "
             f"(expected {expected}), median of {repeats} runs",
             f"  {'stage':34s} {'median ms':>10s} {'p10':>8s} {'p90':>8s}"]
    for stage, t in _time_round_robin(stages, repeats).items():
        lines.append(f"  {stage:34s} {np.median(t):10.2f} {np.percentile(t, 10):8.2f} "
                     f"{np.percentile(t, 90):8.2f}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50, help="timed runs per stage")
    parser.add_argument("--threads", type=int, default=None,
                        help="cv2.setNumThreads(N) first (default: OpenCV's own choice)")
    parser.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real",
                        help="folder of real frames (default: %(default)s)")
    args = parser.parse_args(argv)
    if args.threads is not None:
        cv2.setNumThreads(args.threads)

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"python {platform.python_version()}, numpy {np.__version__}, opencv {cv2.__version__}"
          f", cores {os.cpu_count()}, cv2 threads {cv2.getNumThreads()}, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    rest, pressed = _frames_synthetic()
    for line in bench("synthetic 97-marker frame", rest, pressed, 97, args.repeats):
        print(line)
    real = args.real / "tactip331_raw" / "raw_tactile_image.png"
    if real.is_file():
        image = pc.read_image(real)
        for line in bench("real 331-pin rest frame (raw_tactile_image.png)", image, image, 331,
                          args.repeats):
            print(line)
    else:
        print(f"real frame not found at {real}: skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
