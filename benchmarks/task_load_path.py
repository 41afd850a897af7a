"""How far a frictional tap of the lab's tasks is from its converged load path: the markers
of the same taps pressed along coarser and finer paths (docs/sim2real_log.md, "The load paths of
the frictional taps").

    python benchmarks/task_load_path.py [--tasks edge,edge+shear,surface+shear] [--n 24]
                                        [--seed 23] [--paths 2x4,6x4,6x8] [--ref 12x16]
                                        [--edge-radius R]

Rule 24's reading (docs/sim2real_log.md, "The load paths of the frictional taps"), per radius:

    python benchmarks/task_load_path.py --tasks edge+shear --n 24 --seed 31 \
        --paths 6x4,6x8,6x16,6x32,6x64 --ref 6x128 --edge-radius 0    # and 0.2, 0.5

A path ``TxS`` is a vertical tap in ``T`` load steps (:func:`~tactip_lab.real.tasks.tap_poses`)
and, for a task under shear, the move made in contact in ``S`` steps
(:func:`~tactip_lab.real.tasks.shear_path`; ``S`` is ignored for the plain edge). ``--n`` taps
of each task's protocol are drawn (:func:`~tactip_lab.real.tasks.draw_poses`, seeded by
``--seed``, independent of the runs' own seeds), each pressed on the identified scene with
the task's friction (:data:`~tactip_lab.real.tasks.TASK_FRICTION`) along every path of
``--paths`` and along ``--ref``, the finest; the edge tasks press the block with its edge
rounded by ``--edge-radius`` mm (default :data:`~tactip_lab.real.tasks.EDGE_RADIUS_MM`; 0:
sharp). Printed per task and path: the RMS over taps of each tap's marker RMS distance (mm,
the skin's 331 markers in 3-D) from the reference path's, its median and largest (over the
taps both paths could press), the RMS marker displacement the reference itself makes from
rest (the field's size, for scale), the taps that failed or missed, and the simulated seconds
per tap. No frame is rendered and no model reads anything: this measures the mechanics alone.
Slow: about a minute per task and path at the defaults on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TASKS = ("edge", "edge+shear", "surface+shear")


def parse_path(text: str) -> tuple[int, int]:
    """``TxS`` -> (tap steps, shear steps), both positive integers."""
    try:
        t, s = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"path {text!r}: TxS, two positive integers "
                                         "(tap steps x shear steps), e.g. 6x4") from None
    if t < 1 or s < 1:
        raise argparse.ArgumentTypeError(f"path {text!r}: both step counts must be >= 1")
    return t, s


def press(task: str, row: np.ndarray, offset: float, mu: float, path: tuple[int, int], sim,
          block, *, trace: np.ndarray | None = None) -> np.ndarray | None:
    """(m, 3) the markers (mm) of one tap pressed along ``path``; None when it misses.
    ``trace``: the rest markers (m, 3), to print every step's force on the pad and the
    markers' mean displacement (the skin's drag), sensor frame."""
    from tactip_lab.real import tasks

    tap_steps, shear_steps = path
    indenter = sim.indenter if task == "surface+shear" else block
    steps = tasks.load_path(task, row, sim=sim, indenter=indenter, tap_steps=tap_steps,
                            shear_steps=shear_steps, depth_offset_mm=offset)
    if steps is None:
        return None
    states, _ = sim.continue_path(steps, friction=mu, indenter=indenter)
    if trace is not None:
        print(f"  path {tap_steps}x{shear_steps}: step, force on the pad (N; x, y, z), mean "
              "marker displacement (mm; x, y, z), contact nodes")
        for k, st in enumerate(states):
            f = np.asarray(st.force_vector_N, dtype=float)
            d = (np.asarray(st.markers_mm, dtype=float) - trace).mean(axis=0)
            print(f"    {k + 1:4d}  ({f[0]:+.2f}, {f[1]:+.2f}, {f[2]:+.2f})  "
                  f"({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f})  {len(st.contact_nodes)}")
    return np.asarray(states[-1].markers_mm, dtype=float)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default=",".join(TASKS),
                    help=f"comma-separated, of {', '.join(TASKS)} (default: all)")
    ap.add_argument("--n", type=int, default=24, help="taps per task (default 24)")
    ap.add_argument("--seed", type=int, default=23, help="seed of the taps (default 23)")
    ap.add_argument("--paths", type=lambda s: [parse_path(p) for p in s.split(",")],
                    default=[(2, 4), (6, 4), (6, 8)],
                    help="paths TxS compared with the reference (default 2x4,6x4,6x8)")
    ap.add_argument("--ref", type=parse_path, default=(12, 16),
                    help="the reference path, the finest (default 12x16)")
    ap.add_argument("--trace", type=int, default=None, metavar="K",
                    help="print every step of tap K (1-based) along every path: the force "
                         "on the pad and the skin's drag")
    ap.add_argument("--edge-radius", type=float, default=None,
                    help="the block's edge radius, mm (default: the edge tasks', "
                         "EDGE_RADIUS_MM; 0: sharp)")
    args = ap.parse_args(argv)
    names = [t.strip() for t in args.tasks.split(",") if t.strip()]
    bad = [t for t in names if t not in TASKS]
    if bad or not names:
        ap.error(f"--tasks {args.tasks!r}: one or more of {', '.join(TASKS)}")
    if args.n < 1:
        ap.error(f"--n={args.n}: at least 1")
    if args.trace is not None and not 1 <= args.trace <= args.n:
        ap.error(f"--trace={args.trace}: a tap in 1..--n ({args.n})")
    if args.edge_radius is not None and not 0 <= args.edge_radius <= 10:
        ap.error(f"--edge-radius={args.edge_radius}: in [0, 10] mm")

    from tqdm import tqdm

    import tactip_sim as ts
    from tactip_lab.real import tasks

    root = Path(__file__).resolve().parents[1]
    scene = ts.load_scene(root / "scenes" / "tactip_331_identified.toml")
    sim = ts.Simulator(scene)
    block = (tasks.block_indenter() if args.edge_radius is None else
             ts.Block(*tasks.BLOCK_MM, edge_radius_mm=args.edge_radius))
    rest = np.asarray(sim.rest_state().markers_mm, dtype=float)
    for task in names:
        rows = tasks.draw_poses(task, args.n, args.seed, None)
        offsets = np.random.default_rng([args.seed, 53, 2]).uniform(
            *tasks.EDGE_DEPTH_OFFSET_MM, args.n)
        friction = tasks.TASK_FRICTION[task]
        mus = (np.random.default_rng([args.seed, 53, 3]).uniform(*friction, args.n)
               if isinstance(friction, tuple) else np.full(args.n, float(friction)))
        # the plain edge has no move: its paths differ by their tap steps alone
        norm = (lambda p: (p[0], 1)) if task == "edge" else (lambda p: p)
        paths = list(dict.fromkeys([norm(args.ref)] + [norm(p) for p in args.paths]))
        ref_path = norm(args.ref)
        got: dict[tuple[int, int], list] = {p: [] for p in paths}
        secs: dict[tuple[int, int], float] = {p: 0.0 for p in paths}
        for i in tqdm(range(args.n), desc=task, unit="tap"):
            for p in paths:
                t0 = time.perf_counter()
                try:
                    if args.trace == i + 1:
                        print(f"\n{task}, tap {i + 1}: labels {np.round(rows[i], 2).tolist()}")
                    got[p].append(press(task, rows[i], offsets[i], float(mus[i]), p, sim,
                                        block, trace=rest if args.trace == i + 1 else None))
                except (ValueError, ArithmeticError, ts.ContactError) as exc:
                    got[p].append(exc)
                secs[p] += time.perf_counter() - t0
        ref = got[ref_path]
        ok_ref = [i for i, m in enumerate(ref) if isinstance(m, np.ndarray)]
        size = np.sqrt(np.mean([np.mean(np.sum((ref[i] - rest) ** 2, axis=1)) for i in ok_ref]))
        where = f", {block!r}" if task.startswith("edge") else ""
        print(f"\n{task}: {args.n} taps (seed {args.seed}), friction {friction}{where}; reference "
              f"path {args.ref[0]}x{args.ref[1]}: {len(ok_ref)} taps pressed, RMS marker "
              f"displacement from rest {size:.3f} mm")
        print("| path (tap x shear steps) | RMS from reference (mm) | median | largest | "
              "taps compared | failed / missed | s a tap |")
        print("|---|---|---|---|---|---|---|")
        for p in paths:
            if p == ref_path:
                continue
            d = [float(np.sqrt(np.mean(np.sum((got[p][i] - ref[i]) ** 2, axis=1))))
                 for i in ok_ref if isinstance(got[p][i], np.ndarray)]
            bad_n = sum(not isinstance(m, np.ndarray) for m in got[p])
            label = f"{p[0]}" if task == "edge" else f"{p[0]}x{p[1]}"
            print(f"| {label} | {np.sqrt(np.mean(np.square(d))) if d else float('nan'):.4f} | "
                  f"{np.median(d) if d else float('nan'):.4f} | "
                  f"{max(d) if d else float('nan'):.4f} | {len(d)} | {bad_n} | "
                  f"{secs[p] / args.n:.3f} |")
        print(f"| reference {args.ref[0]}x{args.ref[1]} | – | – | – | {len(ok_ref)} | "
              f"{args.n - len(ok_ref)} | {secs[ref_path] / args.n:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
