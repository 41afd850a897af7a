"""The randomisation study of issue 52: what each value that identification cannot fix does to
the zero-shot surface model, and a model fitted on all of them at once.

    python benchmarks/sim2real_randomisation.py OUT [--n 600] [--real DIR] [--real-raw DIR]

Each variant is one ``tactip sim2real SCENE --task surface`` run (field model, ``--n`` taps,
into ``OUT/<variant>``, resumable) of the identified 331-pin scene with one value moved to an
end of its range; the ranges and their sources:

- simulated indentation (``--depth-range``): 2..5 mm (the lab's label read as the indentation)
  and 0.5..3 mm (the label less the lab's 2 mm work-frame offset), against the default
  0.5..5 that spans both (tactip_lab/real/tasks.py, SURFACE_CONTACT_MM);
- gel modulus 10 and 50 kPa (skin/gel stiffness ratio 90 and 18): the scene's assumed range
  "order 10-50 kPa for Shore OO 10" (scenes/tactip_331.toml);
- marker diameter 1.2 mm: the published scene's assumed value, against the 1.05 mm
  identified from the real rest frame;
- camera noise x3 (read 6 DN, shot 1.5) and lighting x0.5 (LED intensity 30): the scene's
  values are assumed and no range is published or measured, so these factors are chosen, not
  sourced: they say whether the model is sensitive to the value at all.

"randomised" pools every variant's simulated taps (a seeded draw of at most 3 000) into one
field model. Every model is scored zero-shot on the real folders (no real label used), the
figures printed as a markdown table (MAE roll / pitch, deg) and written to OUT/study.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "tactip_331_identified.toml"
REAL = ROOT.parent / "shared" / "real"

VARIANTS: dict[str, list[str]] = {
    "as identified (indentation 0.5-5 mm)": [],
    "indentation 2-5 mm (label as indentation)": ["--depth-range", "2,5"],
    "indentation 0.5-3 mm (label less 2 mm)": ["--depth-range", "0.5,3"],
    "gel 10 kPa (skin/gel 90)": ["--set", "gel.youngs_modulus_kpa=10"],
    "gel 50 kPa (skin/gel 18)": ["--set", "gel.youngs_modulus_kpa=50"],
    "markers 1.2 mm": ["--set", "pins.marker_diameter_mm=1.2"],
    "camera noise x3": ["--set", "imaging.read_noise=6", "--set", "imaging.shot_noise=1.5"],
    "lighting x0.5": ["--set", "lighting.led_intensity=30"],
}


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name.split(" (")[0]).strip("_")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--n", type=int, default=600, help="simulated taps per variant")
    ap.add_argument("--real", default=str(REAL / "tactip331_tap128"))
    ap.add_argument("--real-raw", default=str(REAL / "tactip331_tap_raw"))
    args = ap.parse_args()

    from tactip_lab.fitting.field_model import FieldModel, fields_of, target_scores
    from tactip_lab.real.task_run import folder_columns

    targets = ["pose_4", "pose_5"]
    rows: dict[str, dict] = {}
    pooled: dict[str, list] = {"128x128": [], "raw": []}
    real_points: dict[str, tuple] = {}
    for name, extra in VARIANTS.items():
        out = args.out / _slug(name)
        cmd = [sys.executable, "-m", "tactip_sim.commands", "sim2real", str(SCENE), "--out",
               str(out), "--n", str(args.n), "--real", args.real, "--real-raw", args.real_raw,
               "--no-progress", "--overwrite", *extra]
        print(f"{name}: {' '.join(cmd[3:])}", flush=True)
        subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        s = json.loads((out / "summary.json").read_text())
        rows[name] = {fmt: {d: r["zero_shot"] for d, r in s["real"].items() if r["format"] == fmt}
                      for fmt in ("128x128", "raw")}
        rows[name]["predicted"] = {fmt: f["predicted_by_simulation"]
                                   for fmt, f in s["formats"].items()}
        cols = folder_columns(out / "sim")
        y = np.stack([cols[t] for t in targets], axis=1)
        for fmt, pts_file in (("128x128", "sim128_points.npz"), ("raw", "sim_raw_points.npz")):
            z = np.load(out / pts_file)
            x = fields_of(z["rest"], z["pts"])
            ok = np.all(np.isfinite(x), axis=1)
            pooled[fmt].append((x[ok], y[ok]))
        for d in (args.real, args.real_raw):
            p = out / f"real_{Path(d).name}_points.npz"
            if d not in real_points and p.is_file():
                z = np.load(p)
                c = folder_columns(Path(d))
                real_points[d] = (fields_of(z["rest"], z["pts"]),
                                  np.stack([c[t] for t in targets], axis=1))
    rng = np.random.default_rng(52)
    rows["randomised (all variants pooled)"] = {}
    for fmt, d in (("128x128", args.real), ("raw", args.real_raw)):
        x = np.concatenate([a for a, _ in pooled[fmt]])
        y = np.concatenate([b for _, b in pooled[fmt]])
        pick = rng.permutation(len(x))[:3000]
        m = FieldModel("surface", targets, (0, 0)).fit(x[pick], y[pick])
        xr, yr = real_points[d]
        rows["randomised (all variants pooled)"][fmt] = {d: target_scores(yr, m.predict(xr),
                                                                          targets)}
    print("\n| simulated variant | 128x128 zero-shot MAE roll / pitch (deg) | raw zero-shot MAE "
          "roll / pitch (deg) |\n|---|---|---|")
    for name, r in rows.items():
        cells = []
        for fmt in ("128x128", "raw"):
            z = next(iter(r[fmt].values()), None)
            cells.append("—" if z is None else
                         f"{z['pose_4']['mae']:.2f} / {z['pose_5']['mae']:.2f}")
        print(f"| {name} | {cells[0]} | {cells[1]} |")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "study.json").write_text(json.dumps(rows, indent=2, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
