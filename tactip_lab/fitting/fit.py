"""Fit roll/pitch regressors on a dataset's perceived CoP and score them on others."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.sampling.dataset import Dataset, DatasetError, json_default
from tactip_lab.sampling.reperceive import SHIFT_INPUTS, array_shift

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

    cop_px : (n, 2) perceived centre of pressure, or (n, d) for a vector feature
    (:data:`VECTOR_FEATURES`); angles_deg : (n, 2) roll, pitch
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


VECTOR_FEATURES = {
    "flow": "the growth CoP plus the whole marker array's motion against the rest frame: mean "
            "displacement, displacement-weighted centroid, displacement gradient "
            "(perception/flow.py; 10 numbers)",
}
"""Features of more than two numbers, perceived from a folder's frames (``tactip fit`` /
``evaluate`` / ``features`` on Bristol-layout folders); this project's sweeps store only the
CoP :data:`FEATURES`."""
FOLDER_FEATURES = {**FEATURES, **VECTOR_FEATURES}
"""Every feature ``tactip fit`` can fit on a labelled folder."""


INVARIANT = "invariant"
PRESSURE_INPUTS = ("cop_growth_x_px", "cop_growth_y_px", "deformation_px")
"""The depth-invariant model's polynomial inputs: the growth CoP and the perceived deformation
(mean marker displacement magnitude, recorded by the sweep), which carries the press depth."""
DEFORMATION = PRESSURE_INPUTS[2]
INVARIANT_INPUTS = (*PRESSURE_INPUTS, *SHIFT_INPUTS)
"""Every input of the depth-invariant model: :data:`PRESSURE_INPUTS`, then the marker array's
mean shift (:func:`tactip_lab.sampling.reperceive.array_shift`), which enters linearly."""
SWEEP_FEATURES = {**FOLDER_FEATURES, INVARIANT:
                  "the depth-invariant estimate: a polynomial in the growth CoP and the "
                  "perceived deformation (mean marker displacement; kept where it lowers the "
                  "leave-one-out error on the training data), plus linear terms in the "
                  "marker array's mean shift, fitted on the training grid and the grid spread "
                  "over the test depths (tactip calibrate --depth-invariant; docs/rig.md)"}
"""Every feature a saved model may name (the invariant one is made and scored by
``tactip calibrate`` on its sweeps)."""


def check_feature(feature: str, *, allowed: dict[str, str] = FEATURES) -> str:
    if feature not in allowed:
        raise ValueError(f"feature={feature!r} is not allowed: one of {', '.join(allowed)}")
    return feature


def make_model(order: int, feature: str, image_size: tuple[int, int] | None):
    """An unfitted regressor for ``feature``: :class:`perception.PoseRegressor` on a CoP,
    :class:`perception.vector_regression.VectorRegressor` on a vector feature."""
    import perception as pc

    if check_feature(feature, allowed=FOLDER_FEATURES) in VECTOR_FEATURES:
        from perception.flow import FLOW_NAMES
        from perception.vector_regression import VectorRegressor

        return VectorRegressor(order, input_names=FLOW_NAMES, image_size=image_size)
    return pc.PoseRegressor(order=order, image_size=image_size)


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


def invariant_features(dataset: Dataset | str | Path) -> FeatureTable:
    """A finished dataset's inputs of the depth-invariant model (:data:`INVARIANT_INPUTS`,
    ``cop_px`` (n, 5)) with the poses: the growth CoP and the perceived deformation as the
    sweep recorded them, and the array's mean shift perceived on each sample's stored frame
    (:func:`tactip_lab.sampling.reperceive.array_shift`; a few seconds per hundred samples).

    Raises
    ------
    DatasetError
        The dataset records no deformation (made before it was recorded: rerun the sweep) or
        keeps no rest frame.
    """
    ds = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    t = ds.table()
    if len(t["index"]) and not np.isfinite(t["deformation_px"]).any():
        raise DatasetError(f"{ds.root} records no deformation_px (a dataset made before it was "
                           "recorded): rerun the sweep into a new folder")
    x = np.hstack([np.stack([t[c] for c in PRESSURE_INPUTS], axis=1),
                   array_shift(ds, t["index"]).reshape(-1, len(SHIFT_INPUTS))])
    angles = np.stack([t["roll_deg"], t["pitch_deg"]], axis=1)
    ok = np.all(np.isfinite(x), axis=1)
    res = ds.manifest().get("scene", {}).get("camera", {}).get("resolution", [0, 0])
    return FeatureTable(x[ok], angles[ok], t["depth_mm"][ok], t["index"][~ok].astype(int),
                        (int(res[0]), int(res[1])))


def join_tables(*tables: FeatureTable) -> FeatureTable:
    """The samples of several tables of the same feature and image format as one table (the
    depth-invariant model's training set: the grid at the training depth and spread over the
    test depths). ``dropped`` keeps each table's dropped sample indices, one after the other."""
    if not tables:
        raise ValueError("tables=() is not allowed: join at least one table")
    sizes = {t.image_size for t in tables}
    widths = {t.cop_px.shape[1] for t in tables}
    if len(sizes) > 1 or len(widths) > 1:
        raise DatasetError(f"cannot join tables of different image sizes {sorted(sizes)} or "
                           f"feature widths {sorted(widths)}")
    return FeatureTable(np.concatenate([t.cop_px for t in tables]),
                        np.concatenate([t.angles_deg for t in tables]),
                        np.concatenate([t.depth_mm for t in tables]),
                        np.concatenate([t.dropped for t in tables]), tables[0].image_size)


def fit_invariant(train: FeatureTable, order: int, *, shift: bool = True,
                  deformation: bool | None = None):
    """The depth-invariant model of ``order``: a :class:`VectorRegressor` on
    :data:`INVARIANT_INPUTS`, a polynomial of ``order`` in :data:`PRESSURE_INPUTS` plus one
    linear term per shift component, fitted on ``train`` (:func:`invariant_features`).

    ``deformation=None`` (the default) keeps the deformation's terms only if they lower the
    model's leave-one-out error on ``train`` (:meth:`VectorRegressor.loo_mse`, both angles):
    where the perceived deformation does not tell the depth (every rig source on,
    docs/rig.md), its terms fit noise, and the model is then the polynomial in the growth CoP
    plus the shift (the deformation named in ``unused_inputs``). That question needs a
    training set spread over depths (the training grid and ``train_span``); on one pressed at
    a single depth the terms are kept, unasked. ``True``/``False`` force the choice.

    ``shift=False``: the model without the shift, on :data:`PRESSURE_INPUTS` alone, the
    deformation always in (``deformation`` does not apply; predict from :func:`pressure_part`
    tables; for comparison, docs/rig.md)."""
    from perception.vector_regression import VectorRegressor

    if not shift:
        candidates = [VectorRegressor(order, input_names=PRESSURE_INPUTS,
                                      image_size=train.image_size)]
        train = pressure_part(train)
    else:
        if deformation is None and np.ptp(train.depth_mm) == 0:
            deformation = True  # one depth: nothing to tell the deformation's worth by
        kept = {True: [()], False: [(DEFORMATION,)], None: [(), (DEFORMATION,)]}[deformation]
        candidates = [VectorRegressor(order, input_names=INVARIANT_INPUTS,
                                      image_size=train.image_size, linear_inputs=SHIFT_INPUTS,
                                      unused_inputs=unused) for unused in kept]
    n_coef = len(candidates[0].powers_) + 1
    if len(train.cop_px) < max(3 * (order + 1), n_coef):
        raise DatasetError(f"only {len(train.cop_px)} usable training samples for an order-"
                           f"{order} depth-invariant model ({n_coef} coefficients)")
    if len(candidates) == 1:
        return candidates[0].fit(train.cop_px, train.angles_deg)
    errors = [m.loo_mse(train.cop_px, train.angles_deg) for m in candidates]  # fits each
    return candidates[int(np.argmin(errors))]  # the first (with it) on a tie


def pressure_part(table: FeatureTable) -> FeatureTable:
    """The :data:`PRESSURE_INPUTS` columns of an :func:`invariant_features` table (what
    :func:`depth_signal` asks about: the shift is there for the tilt, not the depth)."""
    return FeatureTable(table.cop_px[:, :len(PRESSURE_INPUTS)], table.angles_deg,
                        table.depth_mm, table.dropped, table.image_size)


DEPTH_SIGNAL_ORDER = 2
DEPTH_SIGNAL_LOW = 0.5
"""Below this, the depth-invariant model's inputs explain less than half of the depth's
variance on its spread training grid: it has no usable pressure signal (docs/rig.md)."""


def depth_signal(table: FeatureTable, order: int = DEPTH_SIGNAL_ORDER) -> float:
    """How much of the press depth the depth-invariant model's polynomial inputs carry
    (:func:`pressure_part` of its table): the leave-one-out
    R² of ``table.depth_mm`` predicted by a least-squares polynomial of ``order`` in the
    inputs (``table.cop_px``, standardised), over the samples of ``table`` — a training grid
    spread over depths (``train_span``). Near 1 the inputs tell the depth, so the model can
    follow it; near or below 0 they do not, and the model can only average over depths.

    Leave-one-out residuals come from the hat matrix, ``e_i / (1 - h_ii)`` (exact for least
    squares), so no refit per sample; inputs that repeat one another (a rank-deficient
    design) are fitted on the span they have.

    Raises
    ------
    DatasetError
        Fewer samples than coefficients + 1, or a table whose depth does not vary.
    """
    from perception.vector_regression import loo_residuals, monomials, vector_powers

    x = np.asarray(table.cop_px, dtype=np.float64)
    y = np.asarray(table.depth_mm, dtype=np.float64)
    powers = vector_powers(order, x.shape[1])
    if len(y) < len(powers) + 2:
        raise DatasetError(f"{len(y)} samples are too few for the depth signal of an order-"
                           f"{order} polynomial ({len(powers) + 1} coefficients)")
    total = float(np.sum((y - y.mean()) ** 2))
    if total <= 1e-12 * max(1.0, float(np.sum(y ** 2))):
        raise DatasetError("the depth does not vary in this table: the depth signal needs a "
                           "grid spread over depths (train_span)")
    sd = x.std(axis=0)
    z = (x - x.mean(axis=0)) / np.where(sd > 0, sd, 1.0)
    a = np.hstack([np.ones((len(z), 1)), monomials(z, powers)])
    return float(1.0 - np.sum(loo_residuals(a, y) ** 2) / total)


def fit_model(train: FeatureTable, order: int, feature: str = DEFAULT_FEATURE):
    """A regressor of ``order`` for ``feature`` (:func:`make_model`) fitted on ``train``."""
    model = make_model(order, feature, train.image_size)
    n_coef = len(model.powers_) + 1
    if len(train.cop_px) < max(3 * (order + 1), n_coef):
        raise DatasetError(f"only {len(train.cop_px)} usable training samples for an order-"
                           f"{order} model of the {feature!r} feature")
    return model.fit(train.cop_px, train.angles_deg)


def save_model(model: Any, path: str | Path, *, feature: str, fitted_on: dict[str, Any]
               ) -> None:
    """Write ``model`` as JSON with what it was fitted on: the CoP ``feature``, the image size
    and ``fitted_on`` (e.g. the scene hash, the data folder). :func:`load_model` and
    ``tactip evaluate`` use it to refuse a model applied to another feature or image format."""
    from tactip_lab.sampling.dataset import atomic_write_text

    data = model.to_dict()
    data["fitted_on"] = {"feature": check_feature(feature, allowed=SWEEP_FEATURES),
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


def load_any_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """:func:`load_model` for a CoP model or a vector-feature model (by its ``format``)."""
    from perception.errors import ModelError
    from perception.vector_regression import VectorRegressor

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ModelError(f"cannot read model file {str(path)!r}: {exc}") from None
    if isinstance(data, dict):
        check_declared(data, path)
    if isinstance(data, dict) and data.get("format") == "perception.VectorRegressor":
        return VectorRegressor.from_dict(data), data.get("fitted_on", {})
    return load_model(path)


ANGLE_NAMES = ("roll_deg", "pitch_deg")
"""What every model of this tool predicts, in this order (``angle_names``): its outputs are
compared with the roll and pitch columns of a folder, and servo steers roll and pitch."""


def check_declared(data: dict[str, Any], path: str | Path) -> None:
    """Every field a model file declares, checked against its use (a hand-edited or foreign
    file is refused naming the field, never scored as if it said something else).

    Raises
    ------
    perception.errors.ModelError
        ``angle_names`` not (roll_deg, pitch_deg) in this order; ``fitted_on.feature`` not a
        feature of this tool.
    """
    from perception.errors import ModelError

    names = data.get("angle_names")
    if names is not None and (not isinstance(names, list | tuple)
                              or list(names) != list(ANGLE_NAMES)):
        raise ModelError(f"{path}: angle_names={names!r}, but a model's outputs are compared "
                         f"with roll then pitch ({', '.join(ANGLE_NAMES)}): a model with its "
                         "outputs in another order or of other angles is not scored; refit it")
    fitted_on = data.get("fitted_on")
    if isinstance(fitted_on, dict):  # (image_size is checked where it is used: evaluate)
        feature = fitted_on.get("feature")
        if feature is not None and feature not in SWEEP_FEATURES:
            raise ModelError(f"{path}: fitted_on.feature={feature!r} is not a feature of this "
                             f"tool ({', '.join(SWEEP_FEATURES)}); refit it")


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
                 f"Feature: {SWEEP_FEATURES[check_feature(feature, allowed=SWEEP_FEATURES)]}.")
    return "\n".join(lines) + "\n"
