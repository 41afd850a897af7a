"""Benchmark of the neo-Hookean reference solve on the default pad (P2, the reference fidelity):
seconds per pose, Newton iterations and load steps, and how far it moves the markers from the
linear solve, optionally against the solver of another git revision in the same run.

Usage::

    python benchmarks/bench_neohookean.py                    # P2, four poses
    python benchmarks/bench_neohookean.py --order 1          # quick
    python benchmarks/bench_neohookean.py --baseline abb2079 # also time revision abb2079
    python benchmarks/bench_neohookean.py --friction 0.5     # with friction, along paths
    python benchmarks/bench_neohookean.py --order 1 --window # deep poses, the window holding pins

With ``--baseline REF`` the package at git revision REF is exported to a temporary folder and
the same poses are solved there in a second process, one pose at a time in alternation with
this checkout (both see the same load on a shared machine); the ratio of the medians and the
largest displacement difference between the two answers are printed.

With ``--friction MU`` each pose is reached along a load path with Coulomb friction instead
(``Simulator.press_path(..., solver="neo_hookean")``, pins stopped at the window): a tap in
``--steps`` steps, and for the plate poses also a re-orientation in contact about the pad's
tip (the rig's path) from the untilted pose at the same depth (from roll 6°, pitch −4° for the
untilted pose). It prints the seconds of each
step (a step is one Newton solve: what one pose costs when the path is walked anyway) and,
beside them, the frictionless press of the same pose.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
# (roll, pitch, depth mm, sphere radius mm or None for the scene's plate)
POSES = ((2.0, -3.0, 1.0, None), (-5.0, 4.0, 1.0, 8.0), (0.0, 0.0, 2.0, None),
         (10.0, -10.0, 1.5, None))
# poses pressed until the window holds pins (--window): the corner pose (2, 7, 8 and 8 pins at
# P1) and two more deep presses (7 and 9), whose load steps are halved on the way
WINDOW_POSES = ((12.0, -8.8, 2.0, None), (12.0, -8.8, 2.6, None), (12.0, -8.8, 2.8, None),
                (12.0, -8.8, 3.0, None), (-10.0, 10.0, 3.0, None), (8.0, 8.0, 3.2, None))


def worker(order: int, index: int, out: str, poses=POSES) -> None:
    """Solve pose ``index`` of ``poses`` with the package on ``sys.path``; write times and u
    to ``out``."""
    import tactip_sim as ts

    scene = ts.load_scene(SCENE)
    sim = ts.Simulator(scene, element_order=order, solver="full")
    roll, pitch, depth, radius = poses[index]
    pose = ts.Pose(roll, pitch, depth)
    indenter = None if radius is None else ts.Sphere(radius)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    nh = sim.press(pose, indenter, solver="neo_hookean", full_field=True)
    dt = time.perf_counter() - t0
    np.savez(out, u=nh.vertex_displacements_mm, seconds=dt, iterations=nh.iterations,
             markers=nh.marker_displacements_mm, load=load, held=nh.pins_on_window)


def friction_run(order: int, mu: float, steps: int) -> None:
    """Time the friction paths of every pose in this process (prints as it goes)."""
    import tactip_sim as ts

    sim = ts.Simulator(ts.load_scene(SCENE), element_order=order)
    print(f"P{order}, {sim.body.space.n_dofs} dofs, friction {mu:g}, {steps} steps per path; "
          f"load {os.getloadavg()[0]:.1f}", flush=True)
    per_step = []
    for roll, pitch, depth, radius in POSES:
        pose = ts.Pose(roll, pitch, depth)
        indenter = None if radius is None else ts.Sphere(radius)
        t0 = time.perf_counter()
        press = sim.press(pose, indenter, solver="neo_hookean")
        t_press = time.perf_counter() - t0
        paths = [("tap", None)]
        if radius is None:  # turned in contact from the untilted pose (or to it)
            tilted = roll != 0.0 or pitch != 0.0
            paths.append(("re-orient", ts.Pose(0.0, 0.0, depth) if tilted
                          else ts.Pose(6.0, -4.0, depth)))
        for name, start in paths:
            states = sim.press_path(pose, indenter, start=start, steps=steps, friction=mu,
                                    solver="neo_hookean",
                                    pivot_mm=None if start is None else sim.tip_mm)
            secs = [s.seconds for s in states]
            per_step += secs
            moved = np.abs(states[-1].markers_mm - press.markers_mm).max()
            print(f"{pose!s:40s} {'plate' if radius is None else f'sphere {radius:g}':10s} "
                  f"{name:9s} {len(states):2d} steps, median {np.median(secs):5.1f} s/step "
                  f"(max {max(secs):5.1f}), {sum(s.iterations for s in states):3d} its; "
                  f"frictionless press {t_press:5.1f} s; markers {moved:.3f} mm from it; "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"median {np.median(per_step):.1f} s per step with friction (P{order})")


def run(python_path: Path, order: int, index: int, tmp: Path, tag: str, window: bool) -> dict:
    out = tmp / f"{tag}_{index}.npz"
    env = dict(os.environ, PYTHONPATH=str(python_path))
    subprocess.run([sys.executable, __file__, "--worker", str(index), "--order", str(order),
                    "--out", str(out)] + (["--window"] if window else []), env=env, check=True)
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--order", type=int, default=2, choices=(1, 2), help="element order")
    ap.add_argument("--baseline", metavar="REF", help="also time the package at git revision REF")
    ap.add_argument("--friction", type=float, metavar="MU",
                    help="reach each pose along load paths with this Coulomb coefficient")
    ap.add_argument("--steps", type=int, default=4, help="steps per path (with --friction)")
    ap.add_argument("--window", action="store_true",
                    help="deep poses where the window holds pins (WINDOW_POSES)")
    ap.add_argument("--only", type=int, nargs="+", metavar="I",
                    help="solve only these poses (indices into the list, from 0)")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker is not None:
        worker(a.order, a.worker, a.out, WINDOW_POSES if a.window else POSES)
        return
    if a.friction is not None:
        friction_run(a.order, a.friction, a.steps)
        return
    import tactip_sim as ts

    with tempfile.TemporaryDirectory(prefix="bench-nh-") as tmpdir:
        tmp = Path(tmpdir)
        base = None
        if a.baseline:
            base = tmp / "baseline"
            base.mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", a.baseline,
                                      "tactip_sim", "scenes"], check=True,
                                     capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        scene = ts.load_scene(SCENE)
        sim = ts.Simulator(scene, element_order=a.order)
        print(f"P{a.order}, {sim.body.space.n_dofs} dofs; seconds per pose: one press in a fresh "
              "process (its first solve, so once-per-body set-up included)")
        rows, ratios = [], []
        for i, (roll, pitch, depth, radius) in enumerate(WINDOW_POSES if a.window else POSES):
            if a.only is not None and i not in a.only:
                continue
            now = run(ROOT, a.order, i, tmp, "now", a.window)
            pose = ts.Pose(roll, pitch, depth)
            lin = sim.press(pose, None if radius is None else ts.Sphere(radius))
            dl = lin.marker_displacements_mm
            rms = 100 * np.linalg.norm(now["markers"] - dl) / np.linalg.norm(dl)
            row = (f"{pose!s:40s} {'plate' if radius is None else f'sphere {radius:g}':10s} "
                   f"{float(now['seconds']):7.1f} s {int(now['iterations']):3d} its  "
                   f"vs linear {rms:4.1f} % RMS  {int(now['held']):2d} pins held  "
                   f"load {float(now['load']):.1f}")
            if base is not None:
                old = run(base, a.order, i, tmp, "old", a.window)
                ratio = float(old["seconds"]) / float(now["seconds"])
                ratios.append(ratio)
                diff = float(np.abs(old["u"] - now["u"]).max())
                row += (f" | {a.baseline}: {float(old['seconds']):7.1f} s "
                        f"{int(old['iterations']):3d} its, x{ratio:.1f}, max |du| {diff:.1e} mm")
            rows.append(float(now["seconds"]))
            print(row, flush=True)
        print(f"median {np.median(rows):.1f} s per pose (neo-Hookean, P{a.order})")
        if ratios:
            print(f"median speed-up over {a.baseline}: x{np.median(ratios):.1f}")


if __name__ == "__main__":
    main()
