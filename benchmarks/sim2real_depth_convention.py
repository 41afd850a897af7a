"""What a data set's tap depth measures, read from its frames: the marker field's spread.

A tap pressed deeper spreads the marker field; at a fixed labelled depth, a tilted tap spreads
it more or less than a square-on one depending on what the depth label measures
(``tactip_lab.real.sim2real.TAP_DEPTHS``). The field's RMS radius (px, all detected markers about
their centroid) needs no reference frame, so it compares a real data set (whose reference is a
tilted tap) with simulated ones. Per folder, least squares

    rms_radius = c0 + c1 d + c2 d² + c3 (1 - cos(roll) cos(pitch))

and ``lambda = c3 / (∂ rms_radius / ∂ d at the mean depth)`` (mm): the depth, per unit of
``1 - cos θ``, that a tilt adds. ``tip_depth_offset`` on a hemisphere of radius R adds R.
The ± is the standard deviation over 200 bootstrap resamplings of the taps.

    python benchmarks/sim2real_depth_convention.py NAME=DIR [NAME=DIR ...]

with Bristol-layout folders of processed 128x128 taps (a ``tactip sim2real`` output's
``sim128`` folder, or real taps). docs/sim2real.md, "What the depth label measures".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def field_spread(folder: str, expected_count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rms radius px, depth mm, (n, 2) angles deg) of every tap of a Bristol folder."""
    from tqdm import tqdm

    import perception as pc
    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.real.sim2real import field_of

    f = BristolFolder.open(folder)
    radius = np.array([field_of(pc.detect_markers(str(p), expected_count=expected_count))[1]
                       for p in tqdm(f.images, desc=Path(folder).name, unit="frame")])
    return radius, f.depth_mm, f.angles_deg


def tilt_depth(radius: np.ndarray, depth: np.ndarray, angles: np.ndarray
               ) -> tuple[float, float, float]:
    """(lambda mm, slope px/mm, residual px) of the least squares above."""
    ok = np.isfinite(radius)
    r, d, a = radius[ok], depth[ok], np.deg2rad(angles[ok])
    x = np.column_stack([np.ones(len(r)), d, d * d, 1.0 - np.cos(a[:, 0]) * np.cos(a[:, 1])])
    c, *_ = np.linalg.lstsq(x, r, rcond=None)
    slope = c[1] + 2.0 * c[2] * d.mean()
    return float(c[3] / slope), float(slope), float(np.std(r - x @ c))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", metavar="NAME=DIR",
                   help="a label and a Bristol-layout folder of 128x128 taps")
    p.add_argument("--expected-count", type=int, default=331, help="pins (default 331)")
    p.add_argument("--boot", type=int, default=200, help="bootstrap resamplings (default 200)")
    args = p.parse_args(argv)
    rng = np.random.default_rng(0)
    print("| taps | n | field spread per mm of depth (px/mm) | lambda (mm) | residual (px) |")
    print("|---|---:|---:|---:|---:|")
    for item in args.folders:
        name, _, folder = item.partition("=")
        if not folder:
            p.error(f"{item!r}: expected NAME=DIR")
        radius, depth, angles = field_spread(folder, args.expected_count)
        lam, slope, res = tilt_depth(radius, depth, angles)
        boot = [tilt_depth(radius[i], depth[i], angles[i])[0]
                for i in (rng.integers(0, len(radius), len(radius)) for _ in range(args.boot))]
        print(f"| {name} | {int(np.isfinite(radius).sum())} | {slope:.3f} | {lam:+.1f} ± "
              f"{np.std(boot):.1f} | {res:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
