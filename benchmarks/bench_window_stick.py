"""What the pins' ends sticking to the window cost: the neo-Hookean press with the ends sliding
on the window and with them stuck where they touched (``window.pin_friction = "stick"``,
docs/fem.md "Pins that stick to the window"), timed in one process, with the load steps and
Newton iterations each took and how far the markers of the two differ.

Usage::

    python benchmarks/bench_window_stick.py                   # P1, the bundled 2 mm mesh
    python benchmarks/bench_window_stick.py --order 2         # P2 (about 2.5 min a stuck press)

Poses: the corner of the protocol box pressed to 2 mm (three ends reach the window) and the
plate pressed flat to 3.6 mm (six).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
POSES = ((12.0, -8.8, 2.0), (0.0, 0.0, 3.6))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--order", type=int, choices=(1, 2), default=1,
                    help="element order of the pad (default 1)")
    a = ap.parse_args()

    import tactip_sim as ts
    from tactip_sim.fem.contact.indenters import place
    from tactip_sim.fem.neohookean.solver import solve_neo_hookean

    sim = ts.Simulator(ts.load_scene(SCENE), element_order=a.order)
    body = sim.body
    rest = body.space.nodes[body.space.candidates]
    print(f"P{a.order}, bundled 2 mm mesh, plate; seconds, load steps / Newton iterations")
    for roll, pitch, depth in POSES:
        pose = ts.Pose(roll, pitch, depth)
        placement = place(ts.Plate(), pose, rest, skin_thickness_mm=body.skin_thickness_mm)
        runs = {}
        for stick in (False, True):
            t0 = time.perf_counter()
            r = solve_neo_hookean(body, placement, depth, markers=body.markers,
                                  window_stick=stick)
            runs[stick] = (time.perf_counter() - t0, r)
        (ts_, slide), (tk, stuck) = runs[False], runs[True]
        d = np.linalg.norm(body.markers.from_field(slide.u, finite=True)[0]
                           - body.markers.from_field(stuck.u, finite=True)[0], axis=1)
        print(f"  {roll:g}/{pitch:g} deg, {depth:g} mm: sliding {ts_:6.1f} s "
              f"({slide.load_steps} / {slide.iterations}), stuck {tk:6.1f} s "
              f"({stuck.load_steps} / {stuck.iterations}), {tk / ts_:.1f}x; markers differ "
              f"by up to {d.max():.3f} mm")


if __name__ == "__main__":
    main()
