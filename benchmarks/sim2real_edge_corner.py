"""What a rounded corner of the block does to an edge model's lateral reading, beside how much
an edge tap depends on the last bits of its gap (docs/sim2real_log.md, "The block's corner, and
an edge tap's floor").

    python benchmarks/sim2real_edge_corner.py RUN [--n 150] [--radii 0.2,0.5,1.0] [--seed 11]
                                              [--tap-steps K] [--base-radius R] [--out DIR]

``RUN`` is a ``tactip sim2real --task edge`` folder; its ``model.json`` reads the taps in the
lab's 128x128 processed format (converted as the run converts its own,
:func:`~tactip_lab.real.tasks.convert_128`) and its ``model_raw.json`` the raw frames.
The same ``--n`` edge taps of the lab's protocol (poses, depth offsets and noise seeded by
``--seed``; :func:`~tactip_lab.real.tasks.simulate_task`, raw frames; each tap pressed in
``--tap-steps`` load steps, default the edge tasks' :data:`~tactip_lab.real.tasks.EDGE_TAP_STEPS`)
are simulated on:

- *sharp*: the block with a sharp edge (:data:`~tactip_lab.real.tasks.BLOCK_MM`; the edge
  tasks' until the nineteenth session, when its edge was rounded by
  :data:`~tactip_lab.real.tasks.EDGE_RADIUS_MM`, rule 24); with ``--base-radius R`` the
  block rounded by R instead (*base r = R*), which the floor then moves;
- *floor*: the same block 2e-12 mm wider, its edge moved out by 1e-12 mm: what
  changes an edge tap's simulated markers that no physical difference explains (the
  friction solve at the block's corner has more than one converged state, and which one it
  finds turns on the last bits of the gap);
- *mesh*: the block as the watertight box mesh the edge tasks pressed until the eighteenth
  session (:class:`~tactip_sim.fem.contact.indenters.MeshIndenter`): the same surface;
- *r = R*: the block with its edge rounded by each radius of ``--radii`` (mm).

Each folder is read as ``tactip evaluate`` reads it (its rest frame the reference, detected,
tracked, :meth:`~tactip_lab.fitting.field_model.FieldModel.predict_points`). Printed per
format, per 2 mm bin of ``pose_2`` (negative beside the edge, positive over the block):
each variant's lateral reading less the sharp (or base) block's, tap by tap (mean and sd,
mm), and the angle MAE (deg, wrapped); then each variant's simulation time per tap. No real
frame is read.
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

BINS_MM = np.arange(-6.0, 6.1, 2.0)
FLOOR_MM = 1e-12
"""How far the *floor* variant moves the block's edge (mm): far below any physical size."""


def variants(radii: list[float], base_radius: float = 0.0) -> dict[str, object]:
    """name -> the block each variant presses: the base block (:func:`base_name`: sharp, or
    rounded by ``base_radius``) first, the floor the base block's."""
    import trimesh

    import tactip_sim as ts
    from tactip_lab.real import tasks

    length, width, height = tasks.BLOCK_MM
    out: dict[str, object] = {
        base_name(base_radius): ts.Block(length, width, height, edge_radius_mm=base_radius),
        "floor": ts.Block(length, width + 2 * FLOOR_MM, height, edge_radius_mm=base_radius),
        "mesh": ts.MeshIndenter(trimesh.creation.box(extents=tasks.BLOCK_MM), name="box"),
    }
    for r in radii:
        out[f"r = {r:g}"] = ts.Block(length, width, height, edge_radius_mm=r)
    return out


def base_name(base_radius: float) -> str:
    """The base variant's name: ``sharp``, or ``base r = R``."""
    return "sharp" if base_radius == 0 else f"base r = {base_radius:g}"


def read_folder(model, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """(labels (n, t), predictions (n, t)) of a simulated folder, read as ``tactip evaluate``
    reads it."""
    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.fitting.references import predict_folder

    f = BristolFolder.open(folder)
    with (f.root / "targets.csv").open(newline="") as fh:
        table = list(csv.DictReader(fh))
    y = np.array([[float(r[t]) for t in model.targets] for r in table])
    return y, predict_folder(model, f)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a tactip sim2real --task edge folder")
    p.add_argument("--n", type=int, default=150, help="simulated taps per variant")
    p.add_argument("--radii", default="0.2,0.5,1.0",
                   help="edge radii of the rounded variants, mm (comma-separated)")
    p.add_argument("--seed", type=int, default=11,
                   help="seed of the taps (the shipped runs' draws are 0 and up)")
    p.add_argument("--tap-steps", type=int, default=None,
                   help="load steps of each tap (default: the edge tasks', EDGE_TAP_STEPS)")
    p.add_argument("--base-radius", type=float, default=0.0,
                   help="the base block's edge radius, mm, which the floor moves and every "
                   "variant is read against (default 0: sharp; the tasks' default is "
                   "EDGE_RADIUS_MM)")
    p.add_argument("--out", type=Path, default=None,
                   help="keep the simulated folders here (default: a temporary folder)")
    args = p.parse_args(argv)
    import json
    import time

    import tactip_sim as ts
    from tactip_lab.fitting.field_model import load_field_model, wrap_deg
    from tactip_lab.real import tasks

    try:
        radii = [float(v) for v in args.radii.split(",") if v.strip()]
    except ValueError:
        p.error(f"--radii {args.radii!r}: comma-separated numbers (mm)")
    if args.n < 10:
        p.error(f"--n {args.n}: at least 10 taps")
    if args.tap_steps is not None and args.tap_steps < 1:
        p.error(f"--tap-steps {args.tap_steps}: at least 1")
    models = {}
    for fmt, name in (("128x128", "model.json"), ("raw", "model_raw.json")):
        path = args.run / name
        if not path.is_file():
            p.error(f"{args.run}: no {name} (a tactip sim2real --task edge folder?)")
        models[fmt] = (path, load_field_model(path))
        if models[fmt][1].task != "edge":
            p.error(f"{path}: a model of task {models[fmt][1].task!r}; this reads plain "
                    "edge taps")
    try:
        blocks = variants(radii, args.base_radius)
    except ValueError as exc:  # IndenterError
        p.error(f"--radii {args.radii!r} / --base-radius {args.base_radius:g}: {exc}")
    scene = ts.load_scene(Path(__file__).resolve().parents[1] / "scenes"
                          / "tactip_331_identified.toml")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        read, seconds = {}, {}
        for name, block in blocks.items():
            folder = root / name.replace(" = ", "_r").replace(" ", "_")
            t0 = time.perf_counter()
            tasks.simulate_task(scene, folder, "edge", args.n, seed=args.seed,
                                tap_steps=args.tap_steps,
                                indenter=block, progress=True)
            timing = json.loads((folder / "timing.json").read_text())
            seconds[name] = (timing.get("seconds_per_tap"), time.perf_counter() - t0)
            folder128 = tasks.convert_128(folder, folder.with_name(folder.name + "_128"),
                                          scene.pins.count)
            read[name] = {"128x128": read_folder(models["128x128"][1], folder128),
                          "raw": read_folder(models["raw"][1], folder)}
    names = list(read)
    for fmt, (path, model) in models.items():
        y, sharp = read[base_name(args.base_radius)][fmt]
        lateral = model.targets.index("pose_2")
        angle = model.targets.index("pose_6")
        print(f"{args.n} simulated edge taps (seed {args.seed}), {fmt}, read by {path}: "
              f"lateral reading less the {base_name(args.base_radius)} block's, tap by tap, "
              "mean (sd) mm; angle MAE deg")
        print("  pose_2 bin (mm)  taps  " + "  ".join(f"{n:>22s}" for n in names))
        for lo, hi in zip(BINS_MM[:-1], BINS_MM[1:], strict=True):
            m = (y[:, lateral] >= lo) & (y[:, lateral] < hi)
            cells = []
            for n in names:
                yy, pr = read[n][fmt]
                assert np.allclose(yy, y)  # the same seeded labels in every folder
                ok = m & np.isfinite(pr[:, lateral]) & np.isfinite(sharp[:, lateral])
                shift = pr[ok, lateral] - sharp[ok, lateral]
                mae = float(np.mean(np.abs(wrap_deg(pr[ok, angle] - yy[ok, angle]))))
                cells.append(f"{shift.mean():+.2f} ({shift.std():.2f}) {mae:5.1f}°")
            print(f"  {lo:+4.0f} … {hi:+4.0f}   {int(m.sum()):5d}  "
                  + "  ".join(f"{c:>22s}" for c in cells))
    print("  simulated seconds per tap (timing.json; wall time of the variant):")
    for n in names:
        per, wall = seconds[n]
        print(f"    {n:8s} {per if per is None else f'{per:.3f}'} s ({wall:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
