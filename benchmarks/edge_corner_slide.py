"""Does the skin slide sideways at the block's edge during a plain edge tap? The reason the
edge taps are pressed at μ 1 (``tasks.FRICTION_ASSUMED``), re-measured for any block and
friction (docs/sim2real_log.md, "One friction for the edge taps").

    python benchmarks/edge_corner_slide.py [--mu 0.5,1] [--edge-radius R] [--steps 6]
                                           [--positions -3,-2,-1,1,2,3] [--depths 1.5,2,2.5]
                                           [--yaws 0,30,60]

Each tap is the edge tasks' own (:func:`~tactip_lab.real.tasks.edge_pose`, the block's top
face tilted as :data:`~tactip_lab.real.tasks.EDGE_CONVENTION` says, pressed vertically in
``--steps`` load steps with Coulomb friction μ): the sensor's centre ``--positions`` mm inside
the block's edge (negative: beside it), the top face ``--depths`` mm past the pad's tip, the
edge at ``--yaws`` degrees. The markers are projected through the identified scene's camera
model (raw 640x480 pixels, no render). A field radial about the contact displaces the
markers every way, so their *mean* displacement is small against their mean displacement's
size; a skin sliding sideways moves them all one way and the two approach each other. Printed
per tap and μ: the ratio |mean displacement| / mean |displacement| (and the two in px), then
per μ the largest and the median ratio over the taps, and how far (RMS px over the markers)
each μ's markers are from the first μ's. No model reads anything.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: comma-separated numbers") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mu", type=floats, default=[0.5, 1.0],
                    help="friction coefficients, each in (0, 3] (default 0.5,1)")
    ap.add_argument("--edge-radius", type=float, default=None,
                    help="the block's edge radius, mm (default: the edge tasks', "
                         "EDGE_RADIUS_MM; 0: sharp)")
    ap.add_argument("--steps", type=int, default=None,
                    help="load steps of the tap (default: the edge tasks', EDGE_TAP_STEPS)")
    ap.add_argument("--positions", type=floats, default=[-3, -2, -1, 1, 2, 3],
                    help="the sensor's centre inside the edge, mm (negative: beside it)")
    ap.add_argument("--depths", type=floats, default=[1.5, 2.0, 2.5],
                    help="the top face past the pad's tip, mm, each in (0, 4]")
    ap.add_argument("--yaws", type=floats, default=[0, 30, 60], help="the edge's angle, deg")
    args = ap.parse_args(argv)
    if not args.mu or not all(0 < m <= 3 for m in args.mu):
        ap.error(f"--mu {args.mu}: each in (0, 3]")
    if args.edge_radius is not None and not 0 <= args.edge_radius <= 10:
        ap.error(f"--edge-radius={args.edge_radius}: in [0, 10] mm")
    if args.steps is not None and args.steps < 1:
        ap.error(f"--steps={args.steps}: at least 1")
    if not args.depths or not all(0 < d <= 4 for d in args.depths):
        ap.error(f"--depths {args.depths}: each in (0, 4] mm")
    if not args.positions or not all(abs(p) <= 10 for p in args.positions):
        ap.error(f"--positions {args.positions}: each within 10 mm of the edge")

    from tqdm import tqdm

    import tactip_sim as ts
    from tactip_lab.real import tasks
    from tactip_sim.render import Renderer

    root = Path(__file__).resolve().parents[1]
    scene = ts.load_scene(root / "scenes" / "tactip_331_identified.toml")
    sim = ts.Simulator(scene)
    ren = Renderer(scene, ts.build_pad(scene))
    block = (tasks.block_indenter() if args.edge_radius is None else
             ts.Block(*tasks.BLOCK_MM, edge_radius_mm=args.edge_radius))
    steps = tasks.EDGE_TAP_STEPS if args.steps is None else args.steps
    tilt = tasks.EDGE_CONVENTION.top_tilt_deg
    r0 = sim.rest_state()
    _, vis0, rest = ren.ground_truth(r0.markers_mm, r0.marker_directions)
    taps = [(p, d, y) for p in args.positions for d in args.depths for y in args.yaws]
    ratios: dict[float, list[float]] = {m: [] for m in args.mu}
    moved: dict[float, list[float]] = {m: [] for m in args.mu}
    lines = []
    for p, d, y in tqdm(taps, unit="tap"):
        depth = tasks.edge_contact_depth(sim, block, p, y, d, tilt_deg=tilt)
        if depth <= 0:
            lines.append(f"| {p:+g} | {d:g} | {y:g} | " + " | ".join("clear" for _ in args.mu)
                         + " |")
            continue
        pose = tasks.edge_pose(p, y, depth, tilt_deg=tilt)
        cells, first = [], None
        for mu in args.mu:
            try:
                states, _ = sim.continue_path(tasks.tap_poses(pose, steps), friction=mu,
                                              indenter=block)
            except (ValueError, ArithmeticError, ts.ContactError) as exc:
                cells.append(f"failed ({str(exc)[:40]})")
                continue
            with np.errstate(invalid="ignore"):
                _, vis, pts = ren.ground_truth(states[-1].markers_mm,
                                               states[-1].marker_directions)
            seen = vis0 & vis
            dxy = (pts - rest)[seen]
            shift = float(np.linalg.norm(dxy.mean(axis=0)))
            size = float(np.linalg.norm(dxy, axis=1).mean())
            ratios[mu].append(shift / size)
            cell = f"{shift / size:.3f} ({shift:.2f} / {size:.2f})"
            if first is None:
                first = np.where(seen[:, None], pts, np.nan)
            else:  # how far this friction's markers are from the first one's
                apart = float(np.sqrt(np.nanmean(np.sum((pts[seen] - first[seen]) ** 2,
                                                        axis=1))))
                moved[mu].append(apart)
                cell += f", {apart:.2f} px from μ {args.mu[0]:g}"
            cells.append(cell)
        lines.append(f"| {p:+g} | {d:g} | {y:g} | " + " | ".join(cells) + " |")
    print(f"\n{block!r}, {steps} load steps, top face tilted {tilt:g} deg; ratio "
          "|mean displacement| / mean |displacement| (px: the two)")
    print("| inside edge (mm) | tip depth (mm) | yaw (deg) | "
          + " | ".join(f"μ {m:g}" for m in args.mu) + " |")
    print("|---|---|---|" + "---|" * len(args.mu))
    print("\n".join(lines))
    for m in args.mu:
        r = np.array(ratios[m])
        if r.size:
            far = (f"; markers RMS {np.median(moved[m]):.3f} px (median), {max(moved[m]):.3f} "
                   f"(largest) from μ {args.mu[0]:g}'s" if moved[m] else "")
            print(f"μ {m:g}: {r.size} taps, ratio largest {r.max():.3f}, median "
                  f"{np.median(r):.3f}{far}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
