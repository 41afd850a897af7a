"""The grasp servo squeezed off its regressor's training depth: the paper's one-depth model
against the depth-invariant one, in closed loop (docs/servo.md, "Squeezed off the training
depth").

    python benchmarks/servo_depth.py --cal DIR --out OUT [--tip A] [--depths 0.5 1 1.5]
                                     [--runs 20] [--seed 1]

DIR: a finished `tactip calibrate --depth-invariant` folder (its `models/tip_X_order2.json`
and `models/invariant/tip_X_order2.json` are servoed). For each squeeze depth and model, a
batch of ``--runs`` plates inside the calibrated range (`tactip servo --batch N
--outside-fraction 0 --curved-fraction 0 --squeeze-depth D`, the same seed for both models,
so the same plates) into OUT/<model>_<depth>/. A batch already finished there is read, not
rerun. Prints a table and writes OUT/servo_depth.png (success and final errors against the
squeeze depth) and OUT/servo_depth.csv.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MODELS = {"paper": "tip_{tip}_order2.json", "invariant": "invariant/tip_{tip}_order2.json"}
LABELS = {"paper": "paper's one-depth model (growth CoP, order 2)",
          "invariant": "depth-invariant model (order 2)"}


def run_batch(model: Path, depth: float, out: Path, runs: int, seed: int) -> None:
    """One `tactip servo` batch into ``out`` (skipped if its batch.csv exists)."""
    if (out / "batch.csv").is_file():
        return
    cmd = [sys.executable, "-m", "tactip_sim.commands", "servo", "--model", str(model),
           "--batch", str(runs), "--outside-fraction", "0", "--curved-fraction", "0",
           "--seed", str(seed), "--squeeze-depth", f"{depth:g}", "--out", str(out),
           "--no-progress", "--no-charts"]
    subprocess.run(cmd, check=True, cwd=ROOT)


def read_batch(folder: Path) -> dict[str, float]:
    with (folder / "batch.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    roll = np.abs([float(r["final_roll_error_deg"]) for r in rows])
    pitch = np.abs([float(r["final_pitch_error_deg"]) for r in rows])
    cop = np.array([float(r["final_cop_offset_mm"]) for r in rows])
    return {"runs": len(rows), "success": sum(r["converged"] == "True" for r in rows),
            "unflagged": sum(r["unflagged_failure"] == "True" for r in rows),
            "timed_out": sum(r["timed_out"] == "True" for r in rows),
            "roll_median": float(np.median(roll)), "roll_max": float(roll.max()),
            "pitch_median": float(np.median(pitch)), "pitch_max": float(pitch.max()),
            "cop_median": float(np.median(cop)), "cop_max": float(cop.max())}


def chart(results: dict[tuple[str, float], dict[str, float]], depths: list[float],
          path: Path, training_depth: float | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
    width = 0.35
    x = np.arange(len(depths))
    for k, name in enumerate(MODELS):
        r = [results[(name, d)] for d in depths]
        off = (k - 0.5) * width
        axes[0].bar(x + off, [v["success"] / v["runs"] * 100 for v in r], width,
                    label=LABELS[name])
        worst = [max(v["roll_max"], v["pitch_max"]) for v in r]
        axes[1].bar(x + off, worst, width)
        axes[2].bar(x + off, [v["cop_max"] for v in r], width)
    axes[1].axhline(1.0, color="k", lw=1, ls="--")
    axes[2].axhline(0.5, color="k", lw=1, ls="--")
    titles = ("runs that succeed (%)", "worst final |roll| or |pitch| error (°)",
              "worst final CoP offset (mm)")
    for ax, title in zip(axes, titles, strict=True):
        ax.set_xticks(x, [f"{d:g} mm" + ("\n(the paper's training depth)"
                                         if d == training_depth else "") for d in depths])
        ax.set_xlabel("squeeze depth")
        ax.set_title(title, fontsize=10)
    axes[0].set_ylim(0, 140)
    axes[0].legend(fontsize=8, loc="upper center")
    fig.suptitle("Grasp servo, plates inside the calibrated range: dashed = success limits")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cal", type=Path, required=True,
                    help="a finished `tactip calibrate --depth-invariant` folder")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--tip", default="A", help="tip whose models are servoed (A)")
    ap.add_argument("--depths", type=float, nargs="+", default=[0.5, 1.0, 1.5],
                    help="squeeze depths, mm (0.5 1 1.5)")
    ap.add_argument("--runs", type=int, default=20, help="plates per batch (20)")
    ap.add_argument("--seed", type=int, default=1, help="batch seed (1)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs={args.runs} must be >= 1")
    if any(not 0 < d <= 3 for d in args.depths):
        ap.error(f"--depths={args.depths} must each lie in (0, 3] mm")
    models = {k: args.cal / "models" / v.format(tip=args.tip) for k, v in MODELS.items()}
    for name, path in models.items():
        if not path.is_file():
            ap.error(f"--cal={args.cal}: no {name} model {path} (run tactip calibrate "
                     "--depth-invariant into it first)")
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for depth in args.depths:
        for name, path in models.items():
            folder = args.out / f"{name}_{depth:g}"
            run_batch(path, depth, folder, args.runs, args.seed)
            results[(name, depth)] = read_batch(folder)
    keys = list(next(iter(results.values())))
    with (args.out / "servo_depth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["model", "squeeze_depth_mm", *keys])
        for (name, depth), r in results.items():
            w.writerow([name, depth, *(r[k] for k in keys)])
    print("| squeeze | model | success | unflagged failures | timed out | |roll| err. median / "
          "max (°) | |pitch| err. median / max (°) | CoP offset median / max (mm) |")
    print("|---|---|---:|---:|---:|---|---|---|")
    for (name, depth), r in results.items():
        print(f"| {depth:g} mm | {name} | {r['success']} / {r['runs']} | {r['unflagged']} | "
              f"{r['timed_out']} | {r['roll_median']:.2f} / {r['roll_max']:.2f} | "
              f"{r['pitch_median']:.2f} / {r['pitch_max']:.2f} | "
              f"{r['cop_median']:.2f} / {r['cop_max']:.2f} |")
    import json

    manifest = json.loads((args.cal / "manifest.json").read_text())
    training = manifest.get("scene", {}).get("protocol", {}).get("training_depth_mm")
    chart(results, args.depths, args.out / "servo_depth.png", training)
    print(f"chart: {args.out / 'servo_depth.png'}")


if __name__ == "__main__":
    main()
