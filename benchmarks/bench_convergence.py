"""Mesh convergence of the default pad: marker positions and force against the mesh size.

The default pad (``scenes/shadow_fingertip.toml``) is pressed by its plate at the same poses on
meshes of decreasing edge length (``fidelity.mesh_edge_mm``), with the reference physics
(P2, neo-Hookean, rods stopped by the window); the markers of successive sizes are compared
(the largest distance over the 97 markers) and the force. The mesh is converged where two
successive sizes agree within ``--tolerance-mm`` at every pose; the finer of that pair is the
``reference`` preset's mesh. Optionally a second pytetwild mesh of the finest size (pytetwild
is not deterministic) measures how much one mesh instance differs from another.

Usage::

    python benchmarks/bench_convergence.py                        # rewrites docs/convergence/
    python benchmarks/bench_convergence.py --sizes 2 1.5 --depths 1 --out /tmp/conv   # quick
    python benchmarks/bench_convergence.py --sizes 1 0.8 --depths 1 --instances 0   # add 0.8 mm
    python benchmarks/bench_convergence.py --sizes 2 1.5 1.25 1 0.8 --no-solve      # tables only

Each press is stored in ``OUT/cases/`` as it finishes; a rerun (e.g. after an interruption)
solves only the missing ones. (The extra pytetwild meshes are not stored: an interrupted
``--instances`` run builds another one for the presses it has left, and each press records its
mesh's tet count.) Prints the table and writes ``summary.json``, ``cases.csv`` and
``convergence.png`` to ``OUT``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from pathlib import Path

import numpy as np

from tactip_sim.commands.args import float_in, scene_key_type

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
SIZES = (2.0, 1.5, 1.25, 1.0)
POSES = ((4.0, -2.0), (12.0, -8.8))  # (roll, pitch) deg: near the centre, a corner of the box


def _pose(text: str) -> tuple[float, float]:
    """``ROLL,PITCH`` in degrees, checked by :class:`tactip_sim.Pose`'s own ranges."""
    import tactip_sim as ts
    from tactip_sim.fem import PoseError

    try:
        roll, pitch = (float(v) for v in text.split(","))
        ts.Pose(roll, pitch, 1.0)
    except PoseError as exc:  # a ValueError: first
        raise argparse.ArgumentTypeError(str(exc)) from None
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a pose is ROLL,PITCH in degrees") from None
    return roll, pitch


def case_name(size: float, depth: float, pose: tuple[float, float], instance: int,
              pin_friction: str = "none") -> str:
    return (f"h{size:g}_d{depth:g}_r{pose[0]:g}_p{pose[1]:g}"
            + (f"_i{instance}" if instance else "")
            + ("" if pin_friction == "none" else f"_{pin_friction}"))


def solve_size(scene, size: float, cases: list[tuple[float, tuple[float, float]]],
               instance: int, out: Path, bar) -> None:
    """Press every (depth, pose) of ``cases`` on the mesh of edge ``size`` (``instance`` > 0: a
    freshly built pytetwild mesh rather than the bundled or cached one), skipping stored ones."""
    import tactip_sim as ts
    from tactip_sim.mesh import tetrahedralise

    stick = scene.window.pin_friction

    def name(d, p):
        return case_name(size, d, p, instance, stick)

    todo = [(d, p) for d, p in cases if not (out / f"{name(d, p)}.npz").is_file()]
    bar.update(len(cases) - len(todo))
    if not todo:
        return
    sized = ts.replace_in(scene, fidelity={"mesh_edge_mm": size, "element_order": 2,
                                           "material_model": "neo_hookean"})
    mesh = tetrahedralise(sized, use_cache=instance == 0)
    sim = ts.Simulator(sized, mesh=mesh)
    for depth, pose in todo:
        bar.set_postfix_str(f"h={size:g} mm, {pose[0]:g}/{pose[1]:g} deg, {depth:g} mm")
        t0 = time.perf_counter()
        state = sim.press(ts.Pose(pose[0], pose[1], depth))
        seconds = time.perf_counter() - t0
        tmp = out / f".{name(depth, pose)}.tmp.npz"
        np.savez(tmp, markers=state.markers_mm, force=state.force_N, seconds=seconds,
                 tets=len(mesh.tets), dofs=sim.body.space.n_dofs, load=os.getloadavg()[0])
        tmp.replace(out / f"{name(depth, pose)}.npz")
        bar.update(1)


def summarise(sizes, depths, poses, cases_dir: Path, tolerance: float,
              pin_friction: str = "none") -> dict:
    def path(size, depth, pose, instance=0):
        return cases_dir / f"{case_name(size, depth, pose, instance, pin_friction)}.npz"

    def load(size, depth, pose, instance=0):
        with np.load(path(size, depth, pose, instance)) as z:
            return {k: z[k] for k in z.files}

    rows, pairs = [], []
    for depth in depths:
        for pose in poses:
            have = [h for h in sizes if path(h, depth, pose).is_file()]
            runs = [load(h, depth, pose) for h in have]
            for h, r in zip(have, runs, strict=True):
                rows.append({"size_mm": h, "depth_mm": depth, "roll_deg": pose[0],
                             "pitch_deg": pose[1], "instance": 0, "tets": int(r["tets"]),
                             "dofs": int(r["dofs"]), "force_N": float(r["force"]),
                             "seconds": float(r["seconds"])})
            for k in range(len(have) - 1):
                h0, h1, a, b = have[k], have[k + 1], runs[k], runs[k + 1]
                d = np.linalg.norm(a["markers"] - b["markers"], axis=1)
                pairs.append({"coarse_mm": h0, "fine_mm": h1, "depth_mm": depth,
                              "roll_deg": pose[0], "pitch_deg": pose[1],
                              "marker_max_mm": float(d.max()), "marker_mean_mm": float(d.mean()),
                              "force_rel": float(b["force"] / a["force"] - 1.0)})
            for h, a in zip(have, runs, strict=True):  # other pytetwild meshes of a size
                for i in range(1, 4):
                    if not path(h, depth, pose, i).is_file():
                        continue
                    b = load(h, depth, pose, i)
                    d = np.linalg.norm(a["markers"] - b["markers"], axis=1)
                    rows.append({"size_mm": h, "depth_mm": depth, "roll_deg": pose[0],
                                 "pitch_deg": pose[1], "instance": i, "tets": int(b["tets"]),
                                 "dofs": int(b["dofs"]), "force_N": float(b["force"]),
                                 "seconds": float(b["seconds"])})
                    pairs.append({"coarse_mm": h, "fine_mm": h, "instance": i,
                                  "depth_mm": depth, "roll_deg": pose[0], "pitch_deg": pose[1],
                                  "marker_max_mm": float(d.max()),
                                  "marker_mean_mm": float(d.mean()),
                                  "force_rel": float(b["force"] / a["force"] - 1.0)})
    converged = None  # the finer of the first pair of sizes within tolerance at every case
    for h0, h1 in zip(sizes, sizes[1:], strict=False):
        these = [p["marker_max_mm"] for p in pairs
                 if p["coarse_mm"] == h0 and p["fine_mm"] == h1 and "instance" not in p]
        if len(these) == len(depths) * len(poses) and max(these) <= tolerance:
            converged = h1
            break
    by_depth = {}
    for depth in depths:
        by_depth[f"{depth:g}"] = None
        for h0, h1 in zip(sizes, sizes[1:], strict=False):
            these = [p["marker_max_mm"] for p in pairs if p["coarse_mm"] == h0 and
                     p["fine_mm"] == h1 and p["depth_mm"] == depth and "instance" not in p]
            if len(these) == len(poses) and max(these) <= tolerance:
                by_depth[f"{depth:g}"] = h1
                break
    return {"scene": str(SCENE.relative_to(ROOT)), "tolerance_mm": tolerance,
            "converged_size_mm_by_depth": by_depth,
            "physics": "P2, neo-Hookean, rods stopped by the window, plate",
            "converged_size_mm": converged, "cases": rows, "pairs": pairs}


def chart(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2))
    pairs = [p for p in summary["pairs"] if "instance" not in p]
    keys = sorted({(p["depth_mm"], p["roll_deg"], p["pitch_deg"]) for p in pairs})
    for depth, roll, pitch in keys:
        sel = [p for p in pairs if (p["depth_mm"], p["roll_deg"], p["pitch_deg"])
               == (depth, roll, pitch)]
        label = f"{depth:g} mm, roll {roll:g}, pitch {pitch:g}"
        ax.plot([p["fine_mm"] for p in sel], [p["marker_max_mm"] for p in sel], "o-",
                label=label)
        cases = [c for c in summary["cases"] if c["instance"] == 0 and
                 (c["depth_mm"], c["roll_deg"], c["pitch_deg"]) == (depth, roll, pitch)]
        ref = cases[-1]["force_N"]
        bx.plot([c["size_mm"] for c in cases], [100 * (c["force_N"] / ref - 1) for c in cases],
                "o-", label=label)
    for p in summary["pairs"]:
        if "instance" in p:
            ax.plot(p["fine_mm"], p["marker_max_mm"], "kx")
    ax.axhline(summary["tolerance_mm"], color="grey", ls="--", lw=1)
    ax.set_xlabel("finer mesh of the pair (mm)")
    ax.set_ylabel("largest marker difference to the next coarser mesh (mm)")
    ax.set_title("markers: successive meshes (x: second mesh, same size)")
    ax.invert_xaxis()
    bx.set_xlabel("mesh edge (mm)")
    bx.set_ylabel("force vs the finest mesh (%)")
    bx.set_title("force")
    bx.invert_xaxis()
    ax.legend(fontsize=7)
    fig.suptitle("Default pad, P2 neo-Hookean: mesh convergence")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=scene_key_type("fidelity.mesh_edge_mm"), nargs="+",
                    default=list(SIZES),
                    help="mesh edges in mm, coarse to fine (default %(default)s)")
    ap.add_argument("--depths", type=float_in(0.0, lo_open=True), nargs="+", default=None,
                    help="press depths in mm (default: the training depth and 2 mm)")
    ap.add_argument("--poses", type=_pose, nargs="+", default=list(POSES),
                    help="ROLL,PITCH pairs in degrees (default 4,-2 12,-8.8)")
    ap.add_argument("--instances", type=int, default=1, choices=range(0, 4),
                    help="extra pytetwild meshes of the finest size (default 1)")
    ap.add_argument("--tolerance-mm", type=float_in(0.0, lo_open=True), default=0.01,
                    help="agreement of successive sizes that counts as converged (0.01)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "convergence",
                    help="output folder (default docs/convergence)")
    ap.add_argument("--pin-friction", choices=("none", "stick"), default="none",
                    help="window.pin_friction of the presses: the pins' ends slide on the "
                         "window (none, the default) or stick where they touch (stick); "
                         "stored as separate cases")
    ap.add_argument("--no-solve", action="store_true",
                    help="only summarise the presses already stored in OUT/cases")
    a = ap.parse_args()
    sizes = sorted(a.sizes, reverse=True)
    if len(sizes) < 2:
        ap.error("--sizes: give at least two mesh sizes")
    from tqdm import tqdm

    import tactip_sim as ts

    scene = ts.load_scene(SCENE, overrides={"window.pin_friction": a.pin_friction})
    depths = a.depths or [scene.protocol.training_depth_mm, 2.0]
    cases = [(d, p) for d in depths for p in a.poses]
    cases_dir = a.out / "cases"
    cases_dir.mkdir(parents=True, exist_ok=True)
    total = len(cases) * (len(sizes) + a.instances)
    with tqdm(total=0 if a.no_solve else total, desc="presses", unit="press",
              disable=a.no_solve or None) as bar:
        for h in [] if a.no_solve else sizes:
            solve_size(scene, h, cases, 0, cases_dir, bar)
        for i in range(1, 0 if a.no_solve else a.instances + 1):
            solve_size(scene, sizes[-1], cases, i, cases_dir, bar)
    summary = summarise(sizes, depths, a.poses, cases_dir, a.tolerance_mm, a.pin_friction)
    if not summary["cases"]:
        ap.error(f"no stored presses of these sizes, depths and poses in {cases_dir}")
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1))
    with (a.out / "cases.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(summary["cases"][0]))
        w.writeheader()
        w.writerows(summary["cases"])
    chart(summary, a.out / "convergence.png")
    print(f"{'size mm':>8} {'depth':>6} {'pose':>12} {'tets':>7} {'force N':>9} {'s/press':>8}")
    for c in summary["cases"]:
        tag = "" if c["instance"] == 0 else f" (mesh #{c['instance'] + 1})"
        print(f"{c['size_mm']:8g} {c['depth_mm']:6g} {c['roll_deg']:5g}/{c['pitch_deg']:<6g} "
              f"{c['tets']:7d} {c['force_N']:9.4f} {c['seconds']:8.1f}{tag}")
    print("successive sizes: largest / mean marker difference (mm), force change")
    for p in summary["pairs"]:
        what = (f"{p['coarse_mm']:g} -> {p['fine_mm']:g}" if "instance" not in p
                else f"{p['fine_mm']:g}: mesh #{p['instance'] + 1}")
        print(f"  {what:>16} {p['depth_mm']:g} mm {p['roll_deg']:g}/{p['pitch_deg']:g}: "
              f"{p['marker_max_mm']:.4f} / {p['marker_mean_mm']:.4f} mm, "
              f"force {100 * p['force_rel']:+.2f} %")
    for depth, conv in [("every depth", summary["converged_size_mm"]),
                        *summary["converged_size_mm_by_depth"].items()]:
        where = depth if depth == "every depth" else f"{depth} mm deep"
        print(f"converged ({where}: successive sizes within {a.tolerance_mm:g} mm at every "
              "pose): " + (f"{conv:g} mm" if conv else "not reached on these sizes"))


if __name__ == "__main__":
    main()
