"""A second readout of the edge angle: turn alignment to simulated templates, beside the saved
kernel ridge model (docs/sim2real_log.md, "A turn-alignment readout of the edge angle").

    python benchmarks/sim2real_edge_turn_readout.py RUN [--shifted RUN ...] [--real DIR]
        [--chart PNG]

``RUN`` is a ``tactip sim2real --task edge [--shear] --out RUN`` folder. Its simulated taps
(every draw: ``sim128[_d<j>]_points.npz`` with ``sim[_d<j>]/targets.csv``) make the
templates: each tap's feature field
(:func:`~tactip_lab.fitting.field_model.field_features`) turned by its own edge angle so that
every edge lies the same way, scaled to unit norm, averaged per ``pose_2`` bin of
:data:`LATERAL_BIN_MM` by ``pose_3`` bin of :data:`DEPTH_BIN_MM` (:func:`build_templates`).
A frame's angle is the turn, on a grid of :data:`TURN_STEP_DEG` refined by a parabola, whose
turned field correlates best with any template (:func:`read_angles`): a difference between
a frame and the templates that is not a turn moves the correlation, not its peak's place.

Printed, angle MAE (deg) of the readout beside that of ``RUN/model.json`` (as
``tactip evaluate`` reads frames):

- ``--shifted RUN2``: on the simulated taps of another run of the same task (draw 0), made
  with other physical values or another model of the sensor (their labels moved to ``RUN``'s
  angle origin, from each run's ``sim/protocol.json``);
- ``--real DIR``: on a real folder's taps as ``RUN`` tracked them
  (``RUN/real_<name>_points.npz``, written when the run scored ``DIR``); with ``--chart``
  its angle error per cell of ``pose_2`` × ``pose_3`` (``sim2real_edge_bins.depth_grid``),
  the saved model beside the readout, one row per real folder.

No model is fitted and nothing is simulated.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactip_lab.fitting.field_model import (  # noqa: E402
    BANDWIDTH,
    field_features,
    grid_nodes,
    remove_affine,
    wrap_deg,
)
from tactip_lab.real.task_run import folder_columns  # noqa: E402

LATERAL_BIN_MM = 1.0
DEPTH_BIN_MM = 0.5
LATERAL_SPAN_MM = (-6.0, 6.0)
DEPTH_SPAN_MM = (3.0, 5.0)
"""The lab's edge label ranges (``tactip_lab.real.tasks``): the templates' bins tile them,
the last depth bin closed."""
TURN_STEP_DEG = 5.0
MIN_TAPS = 3
"""Taps a bin needs to make a template."""


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, np.nan)


def aligned_patterns(rest: np.ndarray, pts: np.ndarray, angles: np.ndarray,
                     label_turn: float) -> np.ndarray:
    """(n, 2k) unit-norm feature fields (the grid part of ``field_features``) of frames
    ``pts`` (n, m, 2), each turned by ``-angle / label_turn`` image degrees: the edge of every
    frame turned to angle 0. NaN rows where a frame has too few markers."""
    k = len(grid_nodes())
    return _unit(np.stack([field_features(rest, p, rotation_deg=-a / label_turn)[:2 * k]
                           for p, a in zip(pts, angles, strict=True)]))


def build_templates(patterns: np.ndarray, lateral: np.ndarray, depth: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(templates (t, 2k) unit norm, their bins' centres (t, 2): pose_2, pose_3): the mean
    aligned pattern of each bin holding at least :data:`MIN_TAPS` finite patterns."""
    ok = np.all(np.isfinite(patterns), axis=1)
    lat_edges = np.arange(LATERAL_SPAN_MM[0], LATERAL_SPAN_MM[1] + 1e-9, LATERAL_BIN_MM)
    dep_edges = np.arange(DEPTH_SPAN_MM[0], DEPTH_SPAN_MM[1] + 1e-9, DEPTH_BIN_MM)
    out, centres = [], []
    for a, b in zip(lat_edges[:-1], lat_edges[1:], strict=True):
        for c, d in zip(dep_edges[:-1], dep_edges[1:], strict=True):
            top = depth <= d if d >= dep_edges[-1] else depth < d
            sel = ok & (lateral >= a) & (lateral < b) & (depth >= c) & top
            if sel.sum() >= MIN_TAPS:
                out.append(_unit(patterns[sel].mean(axis=0)))
                centres.append(((a + b) / 2, (c + d) / 2))
    if not out:
        raise ValueError(f"no bin holds {MIN_TAPS} taps: no template")
    return np.array(out), np.array(centres)


class TurnedFields:
    """A frame's unit-norm feature field at every turn of ``turns`` (deg) at once. Turning a
    frame by R before :func:`field_features` gives R g(R^T node) for the unturned smoothed
    field g (the affine removal commutes with a turn), so each turn is one matrix of kernel
    weights over the reference's markers, computed once per reference. This repeats
    :func:`field_features`' shift, affine removal and smoothing (``smooth_field``) with the
    weights kept: calling :func:`field_features` on each turn's nodes instead gives the same
    numbers, the whole command 3x slower (5 min 16 s against 1 min 38 s with one shifted set,
    the real folder and the chart, 2026-11-30).
    The test holds the two equal, so a change to the feature breaks it, not this silently."""

    def __init__(self, rest: np.ndarray, turns: np.ndarray) -> None:
        rest = np.asarray(rest, dtype=float)
        c = rest.mean(axis=0)
        self.scale = float(np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1))))
        self.rest, self.r = rest, (rest - c) / self.scale
        a = np.radians(np.asarray(turns, dtype=float))
        self.rot = np.stack([np.stack([np.cos(a), -np.sin(a)], -1),
                             np.stack([np.sin(a), np.cos(a)], -1)], -2)  # (T, 2, 2)
        q = np.einsum("kj,tji->tki", grid_nodes(), self.rot)  # R^T node, (T, k, 2)
        self.w = np.exp(-np.sum((q[:, :, None] - self.r[None, None]) ** 2, axis=-1)
                        / (2 * BANDWIDTH ** 2))  # (T, k, m)

    def __call__(self, pts: np.ndarray) -> np.ndarray:
        """(T, 2k) unit-norm fields of one frame ``pts`` (m, 2) at every turn; NaN when fewer
        than half the markers are tracked (as :func:`field_features`)."""
        ok = np.all(np.isfinite(pts), axis=1)
        k = self.w.shape[1]
        if ok.sum() < len(self.r) / 2:
            return np.full((len(self.w), 2 * k), np.nan)
        d = (pts[ok] - self.rest[ok]) / self.scale
        d = remove_affine(self.r[ok], d - np.median(d, axis=0))
        w = self.w[:, :, ok]
        ws = w.sum(axis=2)
        g = (w @ d) / np.maximum(ws, 1e-12)[..., None]
        g[ws < 1e-3] = 0.0
        g = np.einsum("tij,tkj->tki", self.rot, g)
        return _unit(np.concatenate([g[..., 0], g[..., 1]], axis=1))


def read_angles(templates: np.ndarray, rest: np.ndarray, pts: np.ndarray, label_turn: float,
                step: float = TURN_STEP_DEG) -> np.ndarray:
    """(n,) each frame's edge angle (label degrees): the turn whose turned field correlates
    best with any template, refined by a parabola through that template's correlations at
    the neighbouring turns; NaN for a frame with too few markers."""
    turns = np.arange(0.0, 360.0, step)
    fields = TurnedFields(rest, turns)
    out = np.full(len(pts), np.nan)
    for i, p in enumerate(pts):
        s = fields(np.asarray(p, dtype=float)) @ templates.T  # (turns, templates)
        if not np.all(np.isfinite(s)):
            continue
        j, t = np.unravel_index(np.argmax(s), s.shape)
        lo, mid, hi = s[(j - 1) % len(turns), t], s[j, t], s[(j + 1) % len(turns), t]
        curve = lo - 2 * mid + hi
        shift = 0.5 * (lo - hi) / curve if curve < 0 else 0.0
        out[i] = wrap_deg(-(turns[j] + shift * step) * label_turn)
    return out


def _origin(run: Path) -> float:
    """The run's angle origin (deg); its angle sign must be the edge convention's, -1."""
    conv = json.loads((run / "sim" / "protocol.json").read_text())["convention"]
    if conv["angle_sign"] != -1.0:
        raise SystemExit(f"{run}: angle_sign {conv['angle_sign']}, not -1: labels not comparable")
    return float(conv["angle_origin_deg"])


def draws(run: Path) -> list[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]]:
    """(rest, points, labels) of each simulated draw of a run, draw 0 first."""
    out, j = [], 0
    while True:
        tag = "" if j == 0 else f"_d{j}"
        points = run / f"sim128{tag}_points.npz"
        if not points.is_file():
            return out
        z = np.load(points)
        labels = folder_columns(run / f"sim{tag}")
        n = len(z["pts"])
        out.append((z["rest"], z["pts"], {c: v[:n] for c, v in labels.items()}))
        j += 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a tactip sim2real --task edge [--shear] --out folder")
    p.add_argument("--shifted", type=Path, nargs="*", default=[], metavar="RUN",
                   help="runs of the same task simulated with other values or another "
                   "model of the sensor (draw 0 of each is read)")
    p.add_argument("--real", type=Path, nargs="*", default=[], metavar="DIR",
                   help="real folders the run scored (its real_<name>_points.npz)")
    p.add_argument("--chart", type=Path, default=None, metavar="PNG",
                   help="the real folders' angle error per pose_2 x pose_3 cell, both readouts")
    args = p.parse_args(argv)
    if args.chart is not None and not args.real:
        p.error("--chart draws the real folders' errors: give --real DIR")
    from tactip_lab.fitting.field_model import load_field_model

    model = load_field_model(args.run / "model.json")
    if "pose_6" not in model.label_turn:
        raise SystemExit(f"{args.run}/model.json: not an edge model (no turning pose_6)")
    turn = float(model.label_turn["pose_6"])
    sims = draws(args.run)
    pats = np.concatenate([aligned_patterns(r, q, lab["pose_6"], turn) for r, q, lab in sims])
    lat = np.concatenate([lab["pose_2"] for *_, lab in sims])
    dep = np.concatenate([lab["pose_3"] for *_, lab in sims])
    templates, _ = build_templates(pats, lat, dep)
    print(f"{args.run}: {len(templates)} templates from {len(lat)} simulated taps "
          f"({len(sims)} draws)")
    print("| taps | n | turn readout, angle MAE (deg) | saved model | turn readout, median error |")
    print("|---|---:|---:|---:|---:|")
    origin = _origin(args.run)
    sets = []  # (name, reference, frames, labels, real)
    for other in args.shifted:
        rest, pts, lab = draws(other)[0]
        # the block's yaw is -pose_6 + origin: the same yaw is pose_6 + (origin - other's)
        lab = {**lab, "pose_6": wrap_deg(lab["pose_6"] + origin - _origin(other))}
        sets.append((f"simulated {other}", rest, pts, lab, False))
    for folder in args.real:
        z = np.load(args.run / f"real_{folder.name}_points.npz")
        sets.append((f"real {folder.name}", z["rest"], z["pts"], folder_columns(folder),
                     True))
    charted = []
    for name, rest, pts, lab, real in sets:
        got = read_angles(templates, rest, pts, turn)
        saved = model.predict_points(rest, pts)[:, model.targets.index("pose_6")]
        e, es = wrap_deg(got - lab["pose_6"]), wrap_deg(saved - lab["pose_6"])
        print(f"| {name} | {len(e)} | {np.nanmean(np.abs(e)):.2f} | "
              f"{np.nanmean(np.abs(es)):.2f} | {np.nanmedian(e):+.2f} |", flush=True)
        if real:
            charted.append((name, lab, saved, got))
    if args.chart is not None:
        chart(args.chart, charted)
        print(f"chart: {args.chart}")
    return 0


def chart(path: Path, rows: list[tuple[str, dict[str, np.ndarray], np.ndarray, np.ndarray]]
          ) -> None:
    """Per real folder (a row): the median angle error (colour) and MAE (text) per cell of
    ``pose_2`` by ``pose_3``, the saved model's beside the turn readout's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from sim2real_edge_bins import BINS_MM, DEPTH_BINS_MM, depth_grid

    fig, axes = plt.subplots(len(rows), 2, figsize=(10, 3.8 * len(rows)), squeeze=False,
                             layout="constrained")
    image = None
    for (name, lab, saved, got), pair in zip(rows, axes, strict=True):
        truth = np.c_[lab["pose_2"], lab["pose_6"]]
        for ax, pred, what in zip(pair, (saved, got), ("saved model", "turn readout"),
                                  strict=True):
            grid = depth_grid(lab["pose_2"], truth, np.c_[lab["pose_2"], pred], lab["pose_3"])
            med = np.array([[c["centre"] for c in row] for row in grid])
            image = ax.imshow(med, cmap="RdBu_r", vmin=-25, vmax=25, aspect="auto",
                              origin="lower")
            for i, row in enumerate(grid):
                for j, c in enumerate(row):
                    ax.text(j, i, f"{c['mae']:.1f}", ha="center", va="center", fontsize=8)
            mae = np.nanmean(np.abs(wrap_deg(pred - lab["pose_6"])))
            ax.set_title(f"{name}\n{what}: angle MAE {mae:.2f} deg", fontsize=9)
            ax.set_xticks(range(len(DEPTH_BINS_MM) - 1),
                          [f"{a:g}-{b:g}" for a, b in zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:],
                                                          strict=True)])
            ax.set_yticks(range(len(BINS_MM) - 1),
                          [f"{a:+g}..{b:+g}" for a, b in zip(BINS_MM[:-1], BINS_MM[1:],
                                                            strict=True)])
            ax.set_xlabel("pose_3, depth label (mm)")
        pair[0].set_ylabel("pose_2 (mm; + over the block)")
    fig.colorbar(image, ax=axes, label="median angle error (deg); text: MAE", shrink=0.8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
