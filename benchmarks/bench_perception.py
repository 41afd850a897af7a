"""Time the perception stages per 640x480 frame, against the previous implementation.

    python benchmarks/bench_perception.py [--repeats 100] [--threads N] [--real ../shared/real]
                                          [--frames REST FRAME [--expected N]]
                                          [--baseline REV | --no-baseline]

For each frame pair (rest frame, frame) it prints the median (and 10th/90th percentile)
milliseconds per frame of

* ``detect``: ``detect_markers_detailed`` with the sensor region, the marker size and the pixel
  noise measured on the rest frame, as ``FeaturePipeline`` runs it;
* ``detect, frame alone``: ``detect_markers_detailed(frame, expected_count=N)``, a frame read
  with nothing known but its pin count (the ``detect`` command);
* ``track``: ``MarkerTracker.update`` from a reset tracker;
* ``voronoi``: the clipped cell areas of the tracked markers in the pipeline's region, as the
  pipeline computes them (``FeaturePipeline.voronoi``, which reuses the last triangulation while
  it stays Delaunay; the reference implementation has no such state);
* ``cop``: both centres of pressure (cell areas and cell growth);
* ``total``: the four back to back, timed as one unit (not summed);
* ``FeaturePipeline.process``: the whole frame as the calibration sweeps run it (adds grey
  conversion, area change, contact and the result record), as the next frame of a sequence;
* ``process after reset()``: the same for the first frame of a sequence (``reset()`` returns
  the Voronoi triangulation to the rest frame's, and if the contact has flipped Delaunay
  edges the frame pays for a new triangulation; a sweep sample does this once for its frames).

The same stages of the perception package at git revision ``--baseline`` (default 7c8f6c3,
the implementation before the speed work) are timed in the same run, interleaved with the
current ones, and their ratio printed: this machine is shared, and only a comparison made
under the same load means much. Each repeat runs every stage of both once, in a shuffled
order.

Frames: a synthetic 97-marker frame (rest and pressed, ``perception.synthetic``), the real
331-pin rest frame against itself (``--real``), two raw 640x480 331-pin taps, two of the lab's
128x128 binarised taps (a 4-5 mm deep one against a shallow one), and any pair given with
``--frames`` (e.g. a rendered rest frame and a pressed frame from a calibration sweep's
``images/`` folder).
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402

import perception as pc  # noqa: E402
from perception.synthetic import render_markers  # noqa: E402

DEFAULT_BASELINE = "7c8f6c3"


def load_baseline(rev: str, workdir: Path):
    """Import ``perception`` as it was at git revision ``rev`` (as package ``perception_ref``)."""
    target = workdir / "perception_ref"
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "perception"],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(workdir)], input=archive, check=True)
    shutil.move(str(workdir / "perception"), str(target))
    sys.path.insert(0, str(workdir))
    return importlib.import_module("perception_ref")


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


def _stages(lib, rest_image: np.ndarray, image: np.ndarray, expected: int) -> dict:
    """The timed callables for one implementation (``perception`` or the baseline)."""
    pipe = lib.FeaturePipeline(rest_image, expected_count=expected)
    region, diameter = pipe.region, pipe.expected_diameter_px
    tracker = lib.MarkerTracker(pipe.rest_points, rest_areas=pipe.rest.areas_px)
    # as the pipeline detects: with the rest frame's pixel noise where it has one (not the
    # revisions before 2026-11-22, which measure it on every frame)
    opts = dict(mask=region, expected_count=expected, expected_diameter_px=diameter)
    if getattr(pipe.rest, "noise_sigma", None) is not None:  # (same bit depth as the frame)
        opts["noise_sigma"] = pipe.rest.noise_sigma
    det = lib.detect_markers_detailed(image, **opts)
    tracked = tracker.update(det.points, areas=det.areas_px)
    seeds = np.where(np.isnan(tracked), tracker.last_known, tracked)
    voronoi = getattr(pipe, "voronoi", None)  # the baseline has no stateful Voronoi
    areas_of = voronoi.areas if voronoi is not None else (
        lambda pts: lib.voronoi_areas(pts, region))
    areas = areas_of(seeds)

    def detect():
        return lib.detect_markers_detailed(image, **opts)

    def detect_alone():  # a frame read alone, told the pin count only (the detect command)
        return lib.detect_markers_detailed(image, expected_count=expected)

    def track():
        tracker.reset()
        return tracker.update(det.points, areas=det.areas_px)

    def cop():
        lib.centre_of_pressure(tracked, areas, on_empty="nan")
        lib.centre_of_pressure(tracked, areas, weighting="growth",
                               rest_areas=pipe.rest_areas, on_empty="nan")

    def total():
        d = detect()
        tracker.reset()
        p = tracker.update(d.points, areas=d.areas_px)
        a = areas_of(np.where(np.isnan(p), tracker.last_known, p))
        lib.centre_of_pressure(p, a, on_empty="nan")
        lib.centre_of_pressure(p, a, weighting="growth", rest_areas=pipe.rest_areas,
                               on_empty="nan")

    def process():  # the next frame of a sequence (e.g. the noisy frames of one contact)
        pipe.process(image)

    def first():  # the first frame after reset(): the rest frame's triangulation is re-checked
        pipe.reset()
        pipe.process(image)

    return {"detect": detect, "detect, frame alone": detect_alone, "track": track,
            "voronoi": lambda: areas_of(seeds), "cop": cop,
            "total": total, "FeaturePipeline.process": process,
            "process after reset()": first}, det.count


#: The clock of the timings: wall time (default) or this process's CPU time (``--clock cpu``:
#: with one OpenCV thread, what the code costs whatever else loads the machine).
CLOCK = time.perf_counter


def bench(name: str, rest_image: np.ndarray, image: np.ndarray, expected: int, repeats: int,
          baseline) -> list[str]:
    new, count = _stages(pc, rest_image, image, expected)
    impls = {"new": new}
    if baseline is not None:
        impls["ref"], _ = _stages(baseline, rest_image, image, expected)
    calls = [(impl, stage, fn) for stage in new for impl, fns in impls.items()
             for fn in [fns[stage]]]
    for _, _, fn in calls:  # warm-up
        for _ in range(3):
            fn()
    times = {(impl, stage): np.empty(repeats) for impl, stage, _ in calls}
    order = np.random.default_rng(0)
    for i in range(repeats):
        # a fresh order every repeat: whatever ran just before (and what it left in the
        # caches) falls on every stage alike
        for j in order.permutation(len(calls)):
            impl, stage, fn = calls[j]
            t0 = CLOCK()
            fn()
            times[impl, stage][i] = (CLOCK() - t0) * 1e3
    h, w = image.shape[:2]
    lines = [f"{name}: {w}x{h}, {count} markers detected (expected {expected}), "
             f"median of {repeats} runs, ms per frame",
             f"  {'stage':24s} {'median':>8s} {'p10':>7s} {'p90':>7s}"
             + (f" | {'reference':>9s} {'p10':>7s} {'p90':>7s} | {'speed-up':>8s}"
                if baseline is not None else "")]
    for stage in new:
        t = times["new", stage]
        line = (f"  {stage:24s} {np.median(t):8.2f} {np.percentile(t, 10):7.2f} "
                f"{np.percentile(t, 90):7.2f}")
        if baseline is not None:
            r = times["ref", stage]
            line += (f" | {np.median(r):9.2f} {np.percentile(r, 10):7.2f} "
                     f"{np.percentile(r, 90):7.2f} | {np.median(r) / np.median(t):7.1f}x")
        lines.append(line)
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100, help="timed runs per stage")
    parser.add_argument("--threads", type=int, default=None,
                        help="cv2.setNumThreads(N) first (default: OpenCV's own choice)")
    parser.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real",
                        help="folder of real frames (default: %(default)s)")
    parser.add_argument("--frames", type=Path, nargs=2, metavar=("REST", "FRAME"),
                        help="also time this pair of frames (e.g. rendered ones)")
    parser.add_argument("--expected", type=int, default=97,
                        help="marker count of --frames (default: %(default)s)")
    parser.add_argument("--baseline", default=DEFAULT_BASELINE,
                        help="git revision of the reference implementation "
                             "(default: %(default)s)")
    parser.add_argument("--no-baseline", action="store_true", help="time the current code only")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall time (default) or the process's CPU time (use with "
                             "--threads 1 on a loaded machine)")
    args = parser.parse_args(argv)
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    if args.threads is not None:
        cv2.setNumThreads(args.threads)

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"python {platform.python_version()}, numpy {np.__version__}, opencv {cv2.__version__}"
          f", cores {os.cpu_count()}, cv2 threads {cv2.getNumThreads()}, clock {args.clock}, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        baseline = None
        if not args.no_baseline:
            try:
                baseline = load_baseline(args.baseline, Path(tmp))
                print(f"reference: perception at git revision {args.baseline}")
            except (OSError, subprocess.CalledProcessError) as exc:
                print(f"reference at {args.baseline!r} not available ({exc}): current code only")
        cases = [("synthetic 97-marker frame (pressed, against its rest frame)",
                  *_frames_synthetic(), 97)]
        real = args.real / "tactip331_raw" / "raw_tactile_image.png"
        if real.is_file():
            image = pc.read_image(real)
            cases.append(("real 331-pin rest frame (raw_tactile_image.png, against itself)",
                          image, image, 331))
        else:
            print(f"real frame not found at {real}: skipped")
        taps = sorted((args.real / "tactip331_tap_raw" / "images").glob("*.png"))
        if len(taps) >= 2:
            cases.append((f"real 331-pin raw taps ({taps[-1].name} against {taps[0].name})",
                          pc.read_image(taps[0]), pc.read_image(taps[-1]), 331))
        small = args.real / "tactip331_tap128" / "images"
        if (small / "image_501.png").is_file() and (small / "image_822.png").is_file():
            cases.append(("real 331-pin 128x128 binarised taps (image_822.png, 4-5 mm deep, "
                          "against image_501.png)", pc.read_image(small / "image_501.png"),
                          pc.read_image(small / "image_822.png"), 331))
        if args.frames is not None:
            rest_path, frame_path = args.frames
            cases.append((f"{frame_path.name} against {rest_path.name}",
                          pc.read_image(rest_path), pc.read_image(frame_path), args.expected))
        for name, rest_image, image, expected in cases:
            for line in bench(name, rest_image, image, expected, args.repeats, baseline):
                print(line)
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
