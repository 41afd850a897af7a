"""Fit roll/pitch regressors on a dataset's perceived CoP and score them on others."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .dataset import Dataset, DatasetError, json_default

# Table I of the reference paper: R² at depths -0.5 / 0 / +0.5 mm, per tip and order
PAPER_R2 = {
    ("A", 1): (0.91, 0.90, 0.91), ("A", 2): (0.92, 0.91, 0.92), ("A", 3): (0.84, 0.95, 0.67),
    ("B", 1): (0.87, 0.89, 0.72), ("B", 2): (0.89, 0.92, 0.71), ("B", 3): (0.85, 0.94, 0.28),
    ("C", 1): (0.88, 0.88, 0.81), ("C", 2): (0.90, 0.90, 0.82), ("C", 3): (0.76, 0.93, 0.40),
}
PAPER_DEPTHS = (-0.5, 0.0, 0.5)


@dataclass(frozen=True)
class FeatureTable:
    """CoP features and known angles of the usable samples of a dataset.

    cop_px : (n, 2) perceived centre of pressure; angles_deg : (n, 2) roll, pitch
    depth_mm : (n,); dropped : samples without a reliable CoP (listed, never silently used)
    """

    cop_px: np.ndarray
    angles_deg: np.ndarray
    depth_mm: np.ndarray
    dropped: np.ndarray
    image_size: tuple[int, int]


FEATURES = {
    "growth": "CoP weighted by Voronoi cell growth against the rest frame",
    "area": "the paper's CoP, weighted by (clipped) Voronoi cell areas",
    "hull": "the lab's CoP, weighted by Voronoi cell areas bounded by the frame's own marker "
            "hull scaled 1.1 (unclipped)",
}
"""The centre-of-pressure features, by their one name (code, ``--feature``, the
``cop_<name>_x_px`` columns of ``targets.csv``, docs), and what each is. The first is the
default headline feature (docs/calibration.md says why)."""
DEFAULT_FEATURE = next(iter(FEATURES))


def check_feature(feature: str) -> str:
    if feature not in FEATURES:
        raise ValueError(f"feature={feature!r} is not allowed: one of {', '.join(FEATURES)}")
    return feature


def features(dataset: Dataset | str | Path, *, feature: str = DEFAULT_FEATURE) -> FeatureTable:
    """Read a finished dataset's centre-of-pressure feature ``feature`` (a :data:`FEATURES`
    name) with the poses."""
    check_feature(feature)
    ds = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    t = ds.table()
    cop = np.stack([t[f"cop_{feature}_x_px"], t[f"cop_{feature}_y_px"]], axis=1)
    angles = np.stack([t["roll_deg"], t["pitch_deg"]], axis=1)
    ok = np.all(np.isfinite(cop), axis=1)
    res = ds.manifest().get("scene", {}).get("camera", {}).get("resolution", [0, 0])
    return FeatureTable(cop[ok], angles[ok], t["depth_mm"][ok], t["index"][~ok].astype(int),
                        (int(res[0]), int(res[1])))


def fit_model(train: FeatureTable, order: int):
    """A :class:`perception.PoseRegressor` of ``order`` fitted on ``train``."""
    import perception as pc

    if len(train.cop_px) < 3 * (order + 1):
        raise DatasetError(f"only {len(train.cop_px)} usable training samples for an order-"
                           f"{order} model")
    model = pc.PoseRegressor(order=order, image_size=train.image_size)
    return model.fit(train.cop_px, train.angles_deg)


def save_model(model: Any, path: str | Path, *, feature: str, fitted_on: dict[str, Any]
               ) -> None:
    """Write ``model`` as JSON with what it was fitted on: the CoP ``feature``, the image size
    and ``fitted_on`` (e.g. the scene hash, the data folder). :func:`load_model` and
    ``tactip evaluate`` use it to refuse a model applied to another feature or image format."""
    from .dataset import atomic_write_text

    data = model.to_dict()
    data["fitted_on"] = {"feature": check_feature(feature),
                         "image_size": list(model.image_size or []), **fitted_on}
    atomic_write_text(Path(path), json.dumps(data, indent=2, default=json_default) + "\n")


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """A saved model and its ``fitted_on`` record (empty for a model saved without one)."""
    import perception as pc

    model = pc.PoseRegressor.from_json(Path(path))
    fitted_on = json.loads(Path(path).read_text()).get("fitted_on", {})
    if not isinstance(fitted_on, dict):  # a hand-edited file
        raise pc.ModelError(f"{path}: 'fitted_on' must be a JSON object (the feature, image "
                            f"size and data the model was fitted on), not {fitted_on!r}")
    return model, fitted_on


@dataclass(frozen=True)
class ScoreRow:
    tip: str
    order: int
    depth_mm: float  # offset from the training depth
    r2: float
    r2_roll: float
    r2_pitch: float
    rmse_roll_deg: float
    rmse_pitch_deg: float
    n: int
    dropped: int

    def csv_row(self) -> list[str]:
        return [self.tip, str(self.order), f"{self.depth_mm:+.1f}", f"{self.r2:.4f}",
                f"{self.r2_roll:.4f}", f"{self.r2_pitch:.4f}", f"{self.rmse_roll_deg:.4f}",
                f"{self.rmse_pitch_deg:.4f}"]


CSV_HEADER = ["tip", "order", "depth_mm", "r2", "r2_roll", "r2_pitch", "rmse_roll_deg",
              "rmse_pitch_deg"]


def score(model, test: FeatureTable, *, tip: str, depth_offset_mm: float) -> ScoreRow:
    s = model.score(test.cop_px, test.angles_deg)
    return ScoreRow(tip, model.order, depth_offset_mm, float(s.r2_overall), float(s.r2[0]),
                    float(s.r2[1]), float(s.rmse_deg[0]), float(s.rmse_deg[1]), int(s.n),
                    len(test.dropped))


def r2_table_csv(rows: list[ScoreRow]) -> str:
    lines = [",".join(CSV_HEADER)] + [",".join(r.csv_row()) for r in rows]
    return "\n".join(lines) + "\n"


def r2_table_markdown(rows: list[ScoreRow], *, feature: str = DEFAULT_FEATURE) -> str:
    """Laid out like the paper's Table I, ours beside the published numbers."""
    depths = sorted({r.depth_mm for r in rows})
    by = {(r.tip, r.order, r.depth_mm): r for r in rows}
    tips = sorted({r.tip for r in rows})
    orders = sorted({r.order for r in rows})
    head = "| tip | order | " + " | ".join(f"R² at {d:+.1f} mm: ours (paper)" for d in depths)
    lines = [head + " |", "|---|---|" + "---|" * len(depths)]
    for tip in tips:
        for order in orders:
            cells = []
            for d in depths:
                r = by.get((tip, order, d))
                ours = "—" if r is None else f"{r.r2:.3f}"
                paper = PAPER_R2.get((tip, order))
                pub = (f" ({paper[PAPER_DEPTHS.index(d)]:.2f})"
                       if paper is not None and d in PAPER_DEPTHS else "")
                cells.append(ours + pub)
            lines.append(f"| {tip} | {order} | " + " | ".join(cells) + " |")
    lines.append("")
    n = max((r.n for r in rows), default=0)
    lines.append(f"R² is the mean of the roll and pitch R² on each test set ({n} poses); depths "
                 "are relative to the training depth. Paper: Pestell et al., Table I. "
                 f"Feature: {FEATURES[check_feature(feature)]}.")
    return "\n".join(lines) + "\n"
