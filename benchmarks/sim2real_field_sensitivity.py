"""Which scene value moves the marker field's spread per mm of depth (docs/sim2real.md).

    python benchmarks/sim2real_field_sensitivity.py [VARIANT ...]

The real 331-pin taps spread their marker field 0.706 px (128x128 format) per mm of labelled
depth, the simulated ones ~0.89 (benchmarks/sim2real_depth_convention.py). Here the identified
scene at the ``fast`` preset is pressed by a flat plate at 2-5 mm, square on and at six
seeded tilts; the FEM's marker caps go through the camera model (``Renderer.ground_truth``,
no render) into the 128x128 crop of ``tactip sim2real``; the RMS radius of the cap centroids
is fitted against depth. One line per variant of an assumed scene value.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIDE_PX = 446.963
"""Side of ``tactip sim2real``'s crop of this scene (640x480 px -> 128 px; its crop.json)."""
VARIANTS = {
    "nominal": {},
    "skin E/3": {"skin": {"youngs_modulus_kpa": 300.0}},
    "skin E*3": {"skin": {"youngs_modulus_kpa": 2700.0}},
    "gel nu 0.49": {"gel": {"poisson_ratio": 0.49}},
    "gel nu 0.40": {"gel": {"poisson_ratio": 0.40}},
    "pins 1.5 mm": {"pins": {"length_mm": 1.5}},
    "pins 3.5 mm": {"pins": {"length_mm": 3.5}},
}


def spread(scene, tilts: np.ndarray) -> tuple[float, float, float]:
    """(square-on slope, all-taps slope px/mm, field radius at 2 mm px) of ``scene``."""
    import tactip_sim as ts
    from tactip_sim.render import Renderer

    sim = ts.Simulator(scene)
    ren = Renderer(scene, ts.build_pad(scene))
    rows = []
    for depth in (2.0, 3.0, 4.0, 5.0):
        for roll, pitch in [(0.0, 0.0), *map(tuple, tilts)]:
            st = sim.press(ts.Pose(roll, pitch, depth))
            _, visible, blobs = ren.ground_truth(st.markers_mm, st.marker_directions)
            ok = visible & np.isfinite(blobs).all(axis=1)
            b = blobs[ok] * 128.0 / SIDE_PX
            rows.append((depth, roll, pitch, np.sqrt(((b - b.mean(0)) ** 2).sum(1).mean())))
    a = np.array(rows)
    square = a[(a[:, 1] == 0) & (a[:, 2] == 0)]
    return (float(np.polyfit(square[:, 0], square[:, 3], 1)[0]),
            float(np.polyfit(a[:, 0], a[:, 3], 1)[0]), float(square[0, 3]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("variants", nargs="*", metavar="VARIANT",
                   help=f"variants to run (default all): {', '.join(VARIANTS)}")
    args = p.parse_args(argv)
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        p.error(f"unknown variant {unknown[0]!r}: choose from {', '.join(VARIANTS)}")
    sys.path.insert(0, str(ROOT))
    import tactip_sim as ts
    from tactip_sim.scene import apply_preset, replace_in

    base = apply_preset(ts.load_scene(ROOT / "scenes" / "tactip_331_identified.toml"), "fast")
    rng = np.random.default_rng(0)
    tilts = np.column_stack([rng.uniform(-15, 15, 6), rng.uniform(-15, 15, 6)])
    print("| variant | square-on (px/mm) | all taps (px/mm) | field radius at 2 mm (px) |")
    print("|---|---:|---:|---:|")
    for name in args.variants or VARIANTS:
        t0 = time.perf_counter()
        over = VARIANTS[name]
        sq, every, r2 = spread(replace_in(base, **over) if over else base, tilts)
        print(f"| {name} | {sq:.3f} | {every:.3f} | {r2:.2f} |  ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
