"""Whether an edge model's error on real taps is the model's or the real fields': the run's
saved model reads the real folder's frames turned and mirrored, and its tracked taps made
mirror-symmetric (docs/sim2real_log.md, "The edge's shallow error over the block is a
handedness of the real fields").

    python benchmarks/sim2real_edge_handedness.py RUN=REAL_DIR [RUN=REAL_DIR ...] [--picture PNG]

``RUN`` is a ``tactip sim2real --task edge [--shear] --real REAL_DIR --out RUN`` folder: its
``model.json``, the real taps as it tracked them (``real_<name>_points.npz``) and its first
draw of simulated taps (``sim128_points.npz``, ``sim/targets.csv``). Nothing is simulated,
tracked or fitted. The edge task is mirror-symmetric about the edge's normal through the
sensor's axis, so a real field's mirror image about that line is a tap at the mirrored angle.
Printed:

1. *Turned*: the folder's frames turned by 90, 180 and 270 deg (``np.rot90``; a copy in a
   temporary folder, deleted after) and read as ``tactip evaluate`` reads a folder
   (:func:`read_copy`: detected, its reference chosen by the model's rule, tracked), the
   label turned with them: the zero-shot angle MAE and the median error of the shallow taps
   over the block (:data:`OVER_BLOCK_MM`, :data:`SHALLOW_MM`). A model averaged over its turns
   reads them as the folder as recorded, if detection and tracking turn with the frame too.
2. *Mirrored* (the frames flipped top to bottom, read the same way): the label becomes
   ``K - pose_6``, with ``K`` the circular mean of prediction + label over the deep taps
   (:data:`DEEP_MM`), where the model has no bias; ``A = K / 2`` is then the model's own
   axis, the image angle of the edge's normal being ``A - pose_6`` (up to 180 deg, which a
   mirror line does not see). A bias the model makes keeps its sign; a bias the fields carry
   changes it.
3. *By pose_6*: the shallow over-block median error per quartile of the folder's angles. An
   asymmetry fixed to the camera would turn against the edge as the sensor turns.
4. *Made symmetric*: each tap's displacements averaged with their mirror image about the
   line at ``A - pose_6`` through the centre (:func:`symmetrize`), everywhere or only in a
   region (:data:`REGIONS`): what is left of the shallow bias when the field's handedness is
   taken out there.
5. *Handedness of the feature*: the model's feature
   (:func:`~tactip_lab.fitting.field_model.field_features`) of each tap turned so the edge's
   normal lies along the image x axis, averaged over the shallow and the deep taps over the
   block, and the RMS of the mean's antisymmetric part (y to -y) over the RMS of the mean
   (:func:`antisymmetric_share`), real against the run's first draw of simulated taps.

6. With a model that has a readout (``FieldModel.readout``, the plain edge's since the
   seventeenth session): the angle MAE with it and with the regression alone, over every tap,
   the even and the odd rows (rule 20 was decided on the odd ones), and the shallow taps over
   the block. Items 1-5 read through the model as saved, readout included.

7. *The lateral position from the field made symmetric* (rule 28, 2026-12-01): ``pose_2``
   read by the regression (the mean over its turns) from each tap's markers tracked together
   with their mirror images about the line at ``A - pose_6`` (:func:`mirrored_about`: the
   field averaged with its mirror image, its handedness taken out), against the frames as
   recorded: MAE and mean error over the even rows (the rule's diagnosis), per ``pose_3``
   bin. If the handedness moved the lateral reading, it would move here.

``--picture PNG``: the aligned mean feature and its antisymmetric part, real and simulated,
for the shallow taps over the block of the first ``RUN``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tactip_lab.fitting.field_model import (  # noqa: E402
    circular_mean_deg,
    field_features,
    grid_nodes,
    mirror_parts,
    wrap_deg,
)

OVER_BLOCK_MM = 2.0
"""Taps with ``pose_2`` at least this (mm): the sensor's centre over the block, where the
real shallow taps are read worst (docs/sim2real_log.md, "The component count chosen ...")."""
SHALLOW_MM = (3.0, 3.5)
DEEP_MM = (4.5, 5.0)
"""``pose_3`` spans (mm, inclusive) of the shallowest and the deepest quarter of the lab's
3-5 mm edge taps."""
CORE_RADIUS = 0.6
"""Field radii (RMS radius of the rest array) splitting :data:`REGIONS`' core from its rim."""
REGIONS = ("none", "all", "core", "rim", "block side", "other side")
"""Where :func:`symmetrize` averages a field with its mirror image: nowhere, everywhere,
within :data:`CORE_RADIUS` of the centre or beyond it, on the half toward the block (the side
the taps beside the edge press on) or the other half."""


def _unit(deg: np.ndarray) -> np.ndarray:
    a = np.deg2rad(np.asarray(deg, dtype=float))
    return np.stack([np.cos(a), np.sin(a)], axis=-1)


def read_copy(model, real: Path, transform, tmp: Path) -> np.ndarray:
    """(n, t) ``model``'s predictions of the frames of the Bristol folder ``real``, each
    passed through ``transform`` (an image to an image) into ``tmp`` with the folder's
    ``targets.csv``, and read as ``tactip evaluate`` reads a folder: the reference by the
    model's task's rule with the model's rest state, every frame tracked from it."""
    import shutil

    import cv2

    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.fitting.references import predict_folder

    src = BristolFolder.open(real)
    (tmp / "images").mkdir(parents=True, exist_ok=True)
    shutil.copy(real / "targets.csv", tmp / "targets.csv")
    for f in sorted((real / "images").iterdir()):
        im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if im is not None:
            cv2.imwrite(str(tmp / "images" / f.name), np.ascontiguousarray(transform(im)))
    folder = BristolFolder.open(tmp)
    if len(folder) != len(src):
        raise SystemExit(f"{tmp}: {len(folder)} frames read back of {len(src)}")
    return predict_folder(model, folder, expected_count=len(model.rest))


def mirror_partner(rest: np.ndarray, axis_deg: float) -> tuple[np.ndarray, float]:
    """(m,) the index of the rest marker nearest each marker's mirror image across the line
    through the array's centre at image angle ``axis_deg``, and the largest such distance in
    RMS field radii (a lattice symmetric about the line gives 0)."""
    from scipy.spatial import cKDTree

    c = rest.mean(axis=0)
    r = rest - c
    u = _unit(axis_deg)
    m = 2.0 * np.outer(u, u) - np.eye(2)
    dist, j = cKDTree(r).query(r @ m.T)
    return j, float(dist.max() / np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


def region_mask(rest: np.ndarray, axis_deg: float, region: str, block_sign: float = 1.0
                ) -> np.ndarray:
    """(m,) the rest markers in ``region`` (:data:`REGIONS`) for a mirror line at
    ``axis_deg``; ``block_sign`` +1 when the block lies along +(cos, sin)(axis_deg)."""
    c = rest.mean(axis=0)
    r = rest - c
    rho = np.hypot(r[:, 0], r[:, 1]) / np.sqrt(np.mean(np.sum(r ** 2, axis=1)))
    side = block_sign * (r @ _unit(axis_deg))
    masks = {"none": np.zeros(len(r), bool), "all": np.ones(len(r), bool),
             "core": rho < CORE_RADIUS, "rim": rho >= CORE_RADIUS,
             "block side": side > 0, "other side": side <= 0}
    if region not in masks:
        raise ValueError(f"region={region!r}: one of {', '.join(REGIONS)}")
    return masks[region]


def symmetrize(rest: np.ndarray, points: np.ndarray, axis_deg: float,
               mask: np.ndarray | None = None) -> np.ndarray:
    """(m, 2) ``points`` whose displacements from ``rest`` are averaged with their mirror
    image across the line through the array's centre at ``axis_deg`` (the partner marker's
    displacement, mirrored), at the markers of ``mask`` (all when None)."""
    j, _ = mirror_partner(rest, axis_deg)
    u = _unit(axis_deg)
    m = 2.0 * np.outer(u, u) - np.eye(2)
    d = points - rest
    sym = 0.5 * (d + d[j] @ m.T)
    keep = np.ones(len(rest), bool) if mask is None else np.asarray(mask, bool)
    return rest + np.where(keep[:, None], sym, d)


def mirrored_about(rest: np.ndarray, points: np.ndarray, line_deg: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """((2m, 2), (2m, 2)) ``rest`` and ``points`` with their mirror images across the line
    through the rest array's centre at image angle ``line_deg`` appended: tracked together,
    their feature is the frame's field averaged with its mirror image (no partner marker
    needed, unlike :func:`symmetrize`)."""
    c = rest.mean(axis=0)
    u = _unit(line_deg)
    m = 2.0 * np.outer(u, u) - np.eye(2)  # symmetric: the reflection across the line
    return np.r_[rest, c + (rest - c) @ m], np.r_[points, c + (points - c) @ m]


def lateral_made_symmetric(model, rest: np.ndarray, pts: np.ndarray, lab: dict, axis: float
                           ) -> None:
    """Item 7: ``pose_2`` from the even rows' fields as recorded and made symmetric about
    their true line (``axis - pose_6``), the regression alone (no readout moves ``pose_2``)."""
    from tactip_lab.fitting.field_model import fields_of

    def lateral(refs, p):
        return model.predict_turned([fields_of(refs, p, rotation_deg=d,
                                               invariance=model.invariance)
                                     for d in model.turns_deg()])[:, 0]

    even = np.arange(len(pts)) % 2 == 0
    pairs = [mirrored_about(rest, pts[i], axis - lab["pose_6"][i]) for i in np.where(even)[0]]
    truth = lab["pose_2"][even]
    e0 = lateral(rest, pts[even]) - truth
    e1 = lateral(np.stack([a for a, _ in pairs]), np.stack([b for _, b in pairs])) - truth
    print(f"  7. pose_2 from the field made symmetric about A - pose_6 (even rows, {even.sum()} "
          f"taps): MAE {np.abs(e0).mean():.3f} -> {np.abs(e1).mean():.3f} mm, mean error "
          f"{e0.mean():+.3f} -> {e1.mean():+.3f} mm")
    depth = lab["pose_3"][even]
    for lo, hi in ((3.0, 3.5), (3.5, 4.0), (4.0, 4.5), (4.5, 5.0)):
        m = (depth >= lo) & ((depth <= hi) if hi == 5.0 else (depth < hi))
        print(f"     pose_3 {lo:g}-{hi:g} mm ({int(m.sum()):3d}): mean error "
              f"{e0[m].mean():+.2f} -> {e1[m].mean():+.2f} mm")


def split_mirror(feature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((k, 2), (k, 2)) the symmetric and the antisymmetric part, under y to -y, of the grid
    field of one feature (2k [+ 1]; :func:`field_features`' layout, aligned so the mirror line
    is the x axis): a field equal to its mirror image has no antisymmetric part, one reversed
    by it no symmetric part."""
    k = len(grid_nodes())
    return mirror_parts(np.stack([feature[:k], feature[k:2 * k]], axis=1))


def antisymmetric_share(features: np.ndarray) -> float:
    """RMS of the antisymmetric part (:func:`split_mirror`) of the mean of ``features``
    (n, 2k + 1, aligned so the mirror line is the x axis) over the RMS of the mean: 0 for a
    field symmetric about the x axis, 1 for one reversed by it."""
    f = np.nanmean(np.asarray(features, dtype=float), axis=0)
    _, anti = split_mirror(f)
    k = len(anti)
    return float(np.sqrt(np.mean(anti ** 2)) / np.sqrt(np.mean(f[:2 * k] ** 2)))


def aligned_features(rest: np.ndarray, pts: np.ndarray, axis_deg: np.ndarray) -> np.ndarray:
    """(n, 2k + 1) the feature of each tap turned so that its line at ``axis_deg`` (n,) lies
    along the image's x axis."""
    return np.stack([field_features(rest, p, rotation_deg=-float(a))
                     for p, a in zip(pts, axis_deg, strict=True)])


def _cell(labels: dict[str, np.ndarray], depth: tuple[float, float]) -> np.ndarray:
    return ((labels["pose_2"] >= OVER_BLOCK_MM) & (labels["pose_3"] >= depth[0])
            & (labels["pose_3"] <= depth[1]))


def cell_features(rest: np.ndarray, pts: np.ndarray, labels: dict[str, np.ndarray],
                  depth: tuple[float, float], axis: float) -> tuple[np.ndarray, int]:
    """((n, 2k + 1), n) the aligned features (:func:`aligned_features`, mirror line at
    ``axis - pose_6``) of the taps over the block pressed within ``depth``."""
    m = _cell(labels, depth)
    return aligned_features(rest, pts[m], axis - labels["pose_6"][m]), int(m.sum())


def _sets(run: Path, real: Path) -> list[tuple[np.ndarray, np.ndarray, dict]]:
    """[(rest, points, labels)] of the real folder as ``run`` tracked it and of the run's
    first simulated draw."""
    from tactip_lab.real.task_run import folder_columns

    z = np.load(run / f"real_{real.name}_points.npz")
    s = np.load(run / "sim128_points.npz")
    return [(z["rest"], z["pts"], folder_columns(real)),
            (s["rest"], s["pts"], folder_columns(run / "sim"))]


def _err(model, rest, pts, truth6):
    return wrap_deg(model.predict_points(rest, pts)[:, 1] - truth6)


def report(run: Path, real: Path) -> float:
    """Print the five tables for ``run`` on ``real``; returns the model's axis ``A`` (deg)."""
    import tempfile

    from tactip_lab.fitting.field_model import load_field_model
    from tactip_lab.real.task_run import folder_columns

    if not (run / "model.json").is_file():
        raise SystemExit(f"{run}: no model.json (RUN is a tactip sim2real --task edge --out "
                         "folder)")
    model = load_field_model(run / "model.json")
    if model.targets[:2] != ["pose_2", "pose_6"]:
        raise SystemExit(f"{run}: targets {model.targets}; an edge run predicts "
                         "pose_2, pose_6")
    points = run / f"real_{real.name}_points.npz"
    if not points.is_file():
        raise SystemExit(f"{run}: no {points.name}: RUN did not score {real} (tactip "
                         "sim2real ... --real REAL_DIR)")
    z = np.load(points)
    rest, pts = z["rest"], z["pts"]
    lab = folder_columns(real)
    if len(lab["pose_6"]) != len(pts):
        raise SystemExit(f"{real}: {len(lab['pose_6'])} rows, {points} {len(pts)} taps")
    shallow, deep = _cell(lab, SHALLOW_MM), lab["pose_3"] >= DEEP_MM[0]
    print(f"{run} on {real} ({len(pts)} taps; shallow over the block: pose_2 >= "
          f"{OVER_BLOCK_MM:g} mm, pose_3 {SHALLOW_MM[0]:g}-{SHALLOW_MM[1]:g} mm, "
          f"{int(shallow.sum())} taps)")
    e0 = _err(model, rest, pts, lab["pose_6"])
    print("  1. frames turned: angle MAE / shallow over-block median error (deg)")
    print(f"       0 deg (the run's own reading)   {np.abs(e0).mean():6.2f}   "
          f"{np.median(e0[shallow]):+6.1f}")
    with tempfile.TemporaryDirectory(prefix="handedness_") as tmp:
        for k in (1, 2, 3):
            pred = read_copy(model, real, lambda im, k=k: np.rot90(im, k), Path(tmp) / f"t{k}")
            # np.rot90 turns the image angle atan2(y, x) (y down) by -90 deg per k
            e = wrap_deg(pred[:, 1] - (lab["pose_6"] + 90.0 * k))
            print(f"     {90 * k:3d} deg                         {np.abs(e).mean():6.2f}   "
                  f"{np.median(e[shallow]):+6.1f}")
        pred_m = read_copy(model, real, lambda im: im[::-1], Path(tmp) / "m")[:, 1]
    k = circular_mean_deg((pred_m + lab["pose_6"])[deep])
    em = wrap_deg(pred_m - (k - lab["pose_6"]))
    axis = 0.5 * k
    print(f"  2. frames mirrored (K = {k:.1f} deg from {int(deep.sum())} deep taps; the model's "
          f"axis A = {axis:.1f} deg): angle MAE {np.abs(em).mean():.2f}, shallow over-block "
          f"median {np.median(em[shallow]):+.1f}")
    q = np.quantile(lab["pose_6"], [0.0, 0.25, 0.5, 0.75, 1.0])
    cells = []
    for i in range(4):
        m = shallow & (lab["pose_6"] >= q[i]) & ((lab["pose_6"] <= q[i + 1]) if i == 3
                                                  else (lab["pose_6"] < q[i + 1]))
        cells.append(f"{q[i]:.0f}…{q[i + 1]:.0f}: {np.median(e0[m]):+.1f} ({int(m.sum())})")
    print("  3. shallow over-block median error by pose_6 quartile: " + ", ".join(cells))
    line = axis - lab["pose_6"]
    # the block's side: where the taps beside the edge press (their field leans that way)
    beside = (lab["pose_2"] <= -3.0) & deep
    c = rest.mean(axis=0)
    lean = []
    for i in np.where(beside)[0]:
        d = np.linalg.norm(pts[i] - rest, axis=1)
        ok = np.isfinite(d)
        w = d[ok] / d[ok].sum()
        lean.append(float(((rest[ok] - c) * w[:, None]).sum(axis=0) @ _unit(line[i])))
    sign = 1.0 if np.median(lean) > 0 else -1.0
    print("  4. made symmetric about A - pose_6: shallow over-block median error / MAE (deg)")
    idx = np.where(shallow)[0]
    for region in REGIONS:
        sym = np.stack([symmetrize(rest, pts[i], line[i],
                                   region_mask(rest, line[i], region, sign)) for i in idx])
        e = _err(model, rest, sym, lab["pose_6"][idx])
        print(f"     {region:<11} {np.median(e):+6.1f} / {np.abs(e).mean():5.1f}")
    print("  5. antisymmetric share of the aligned mean feature over the block (real / "
          "simulated)")
    for name, depth in (("shallow", SHALLOW_MM), ("deep", DEEP_MM)):
        (fr, nr), (fs, ns) = (cell_features(r_, p_, l_, depth, axis)
                              for r_, p_, l_ in _sets(run, real)[:2])
        print(f"     {name:<8} {antisymmetric_share(fr):.3f} ({nr} taps) / "
              f"{antisymmetric_share(fs):.3f} ({ns} taps)")
    if model.readout:
        readout, model.readout = model.readout, {}
        e_reg = _err(model, rest, pts, lab["pose_6"])
        model.readout = readout
        odd = np.arange(len(e0)) % 2 == 1
        print(f"  6. the model's {readout['kind']} readout (axis {readout['axis_deg']:.2f} deg) / "
              "the regression alone: angle MAE (deg)")
        for name, m in (("every tap", np.ones(len(e0), bool)), ("even rows", ~odd),
                        ("odd rows", odd), ("shallow over the block", shallow)):
            print(f"     {name:<23} {np.abs(e0[m]).mean():6.2f} / {np.abs(e_reg[m]).mean():6.2f}")
    lateral_made_symmetric(model, rest, pts, lab, axis)
    return axis


def picture(run: Path, real: Path, axis: float, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nodes = grid_nodes()
    fig, axes = plt.subplots(2, 2, figsize=(9, 9))
    for col, (name, (rest, pts, lab)) in enumerate(zip(("real", "simulated"),
                                                       _sets(run, real), strict=True)):
        feats, n = cell_features(rest, pts, lab, SHALLOW_MM, axis)
        f = np.nanmean(feats, axis=0)
        _, anti = split_mirror(f)
        k = len(nodes)
        for row, (g, scale, what) in enumerate(
                ((np.stack([f[:k], f[k:2 * k]], axis=1), 1.0, "mean feature"),
                 (anti, 4.0, "its antisymmetric part ×4"))):
            ax = axes[row, col]
            ax.quiver(nodes[:, 0], nodes[:, 1], scale * g[:, 0], scale * g[:, 1], angles="xy",
                      scale_units="xy", scale=4.0, width=0.004)
            ax.add_patch(plt.Circle((0, 0), 1.41, fill=False, lw=0.6))
            ax.axhline(0.0, lw=0.5, color="0.6")
            ax.set_aspect("equal")
            ax.set_xlim(-1.6, 1.6)
            ax.set_ylim(-1.6, 1.6)
            ax.set_title(f"{name}, {n} taps: {what}", fontsize=9)
    fig.suptitle(f"Shallow taps over the block (pose_2 >= {OVER_BLOCK_MM:g} mm, pose_3 "
                 f"{SHALLOW_MM[0]:g}-{SHALLOW_MM[1]:g} mm), turned so the edge's normal is "
                 "the x axis (field radii)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("pairs", nargs="+", metavar="RUN=REAL_DIR",
                   help="a tactip sim2real --task edge run and the real folder it scored")
    p.add_argument("--picture", type=Path, default=None, metavar="PNG",
                   help="draw the first pair's aligned mean feature and its antisymmetric part")
    args = p.parse_args(argv)
    pairs = []
    for pair in args.pairs:
        if "=" not in pair:
            p.error(f"expected RUN=REAL_DIR, got {pair!r}")
        pairs.append(tuple(Path(x) for x in pair.split("=", 1)))
    first = None
    for run, real in pairs:
        axis = report(run, real)
        first = first or (run, real, axis)
    if args.picture is not None:
        picture(*first, args.picture)
    return 0


if __name__ == "__main__":
    sys.exit(main())
