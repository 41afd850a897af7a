"""Pose regression: centre of pressure (x, y) -> roll and pitch, by polynomial least squares.

The model is the seed paper's: a multivariate polynomial of order 1, 2 or 3 in the CoP,
fitted by ordinary least squares, one output per angle. It is written in numpy (the design
matrix is the same as scikit-learn's ``PolynomialFeatures(include_bias=False)`` in the same
feature order, and the fit is ``LinearRegression``'s), so that

* a saved model is plain JSON - exponents, feature names, coefficients, intercepts and the
  image geometry - and loading it needs neither scikit-learn nor pickles;
* ``predict`` of a loaded model runs the very same code on the very same numbers as the
  fitted one, so the predictions are identical.

The CoP is normalised before the features are formed, ``u = (x - cx) / s``,
``v = (y - cy) / s``, which keeps the 3rd-order design matrix well conditioned. With
``image_size=(w, h)`` the normalisation is fixed by the image: ``c = ((w - 1) / 2, (h - 1) / 2)``,
``s = max(w, h) / 2``; a model fitted on one image size can then be applied to CoPs measured
at another (``predict(..., image_size=...)`` rescales them first). Without it, ``c`` and ``s``
come from the training CoPs (mean and largest per-axis standard deviation).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from itertools import combinations_with_replacement
from os import PathLike
from pathlib import Path

import numpy as np

from .errors import ModelError, PerceptionError

__all__ = ["PoseRegressor", "RegressionScore", "average_frames", "polynomial_powers"]

_FORMAT = "perception.PoseRegressor"
_FORMAT_VERSION = 1


def polynomial_powers(order: int) -> np.ndarray:
    """Exponents of the monomials in (u, v) of degree 1..order, scikit-learn's order.

    Parameters
    ----------
    order : int, 1..3 (any >= 1 works)

    Returns
    -------
    powers : (n_features, 2) int
        Row k is the exponent of u and v in feature k (e.g. order 2: u, v, u², u v, v²).
    """
    rows = []
    for degree in range(1, order + 1):
        for combo in combinations_with_replacement(range(2), degree):
            rows.append(np.bincount(combo, minlength=2))
    return np.array(rows, dtype=np.int64)


def _feature_names(powers: np.ndarray) -> list[str]:
    names = []
    for pu, pv in powers:
        parts = [f"{s}^{p}" if p > 1 else s for s, p in (("u", pu), ("v", pv)) if p > 0]
        names.append(" ".join(parts))
    return names


def _as_2col(values: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1 and arr.shape == (2,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise PerceptionError(f"{name} must have shape (n, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise PerceptionError(f"{name} contains NaN or inf (drop unreliable frames first)")
    return arr


@dataclass(frozen=True)
class RegressionScore:
    """Goodness of fit on one data set.

    Attributes
    ----------
    r2 : (2,) float64
        Coefficient of determination per angle (1 - SS_res / SS_tot); can be negative.
    r2_overall : float
        Mean of the two angles' R².
    rmse_deg : (2,) float64, degrees
        Root-mean-square error per angle.
    n : int
        Number of samples.
    angle_names : tuple of str
    """

    r2: np.ndarray
    r2_overall: float
    rmse_deg: np.ndarray
    n: int
    angle_names: tuple[str, str] = ("roll_deg", "pitch_deg")


def model_json(data: dict, path: str | PathLike[str] | None = None) -> str:
    """A fitted model's dict as JSON text (floats at full precision), also written to ``path``
    when given; shared by :class:`PoseRegressor` and the vector regressor."""
    text = json.dumps(data, indent=2)
    if path is not None:
        Path(path).write_text(text + "\n", encoding="utf-8")
    return text


def score_predictions(angles_deg: np.ndarray, predicted_deg: np.ndarray,
                      angle_names: tuple[str, ...]) -> RegressionScore:
    """R² (1 - residual / total sum of squares) and RMSE per angle of predictions against the
    true angles, both (n, k) with n >= 2."""
    y, pred = np.asarray(angles_deg, dtype=np.float64), np.asarray(predicted_deg)
    res = ((y - pred) ** 2).sum(axis=0)
    tot = ((y - y.mean(axis=0)) ** 2).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.where(tot > 0, 1.0 - res / tot, np.nan)
    return RegressionScore(r2=r2, r2_overall=float(np.mean(r2)),
                           rmse_deg=np.sqrt(res / len(y)), n=len(y), angle_names=angle_names)


class PoseRegressor:
    """Polynomial regression from CoP (x, y) to two angles (roll, pitch).

    Parameters
    ----------
    order : {1, 2, 3}
        Polynomial order (the seed paper compares all three and uses 2).
    image_size : (w, h), px, optional
        Image geometry the CoPs refer to; fixes the normalisation (see module docstring).
    angle_names : (2,) str
        Names of the two outputs, saved with the model.

    Attributes
    ----------
    coef_ : (2, n_features) float64, degrees per normalised unit^k
        Coefficients of each angle on the features ``feature_names_`` (None until fitted).
    intercept_ : (2,) float64, degrees
        None until fitted.
    powers_ : (n_features, 2) int
        Exponents of u and v in each feature.
    feature_names_ : list of str
        ``"u"``, ``"v"``, ``"u^2"``, ``"u v"``, ...
    centre_px_ : (2,) float64, px
        CoP normalisation centre (None until fitted).
    scale_px_ : float, px
        CoP normalisation scale (None until fitted).
    """

    def __init__(self, order: int = 2, *, image_size: tuple[int, int] | None = None,
                 angle_names: tuple[str, str] = ("roll_deg", "pitch_deg")) -> None:
        if isinstance(order, bool) or order not in (1, 2, 3):
            raise PerceptionError(f"order={order!r} must be 1, 2 or 3")
        self.order = int(order)
        self.image_size = None if image_size is None else _check_size(image_size)
        if len(angle_names) != 2:
            raise PerceptionError(f"angle_names must name 2 angles, got {angle_names!r}")
        self.angle_names = (str(angle_names[0]), str(angle_names[1]))
        self.powers_ = polynomial_powers(self.order)
        self.feature_names_ = _feature_names(self.powers_)
        self.coef_: np.ndarray | None = None
        self.intercept_: np.ndarray | None = None
        self.centre_px_: np.ndarray | None = None
        self.scale_px_: float | None = None

    # -- features -------------------------------------------------------------------------
    def features(self, cop_xy: np.ndarray, *, image_size: tuple[int, int] | None = None
                 ) -> np.ndarray:
        """Design matrix (without the constant column) for CoPs.

        Parameters
        ----------
        cop_xy : (n, 2) float, px, OpenCV (x, y)
        image_size : (w, h), optional
            Size of the images these CoPs come from, if different from the model's; the CoPs
            are rescaled to the model's image size first.

        Returns
        -------
        X : (n, n_features) float64
        """
        self._check_fitted()
        cop = _as_2col(cop_xy, "cop_xy")
        if image_size is not None:
            if self.image_size is None:
                raise ModelError("image_size given but the model was fitted without image_size")
            w, h = _check_size(image_size)
            cop = cop * (np.array(self.image_size, dtype=np.float64) / (w, h))
        uv = (cop - self.centre_px_) / self.scale_px_
        return np.prod(uv[:, None, :] ** self.powers_[None, :, :], axis=2)

    # -- fit / predict / score --------------------------------------------------------------
    def fit(self, cop_xy: np.ndarray, angles_deg: np.ndarray) -> PoseRegressor:
        """Least-squares fit.

        Parameters
        ----------
        cop_xy : (n, 2) float, px
            Training CoPs, finite.
        angles_deg : (n, 2) float, degrees
            Roll and pitch per sample, finite.

        Returns
        -------
        self
        """
        cop = _as_2col(cop_xy, "cop_xy")
        y = _as_2col(angles_deg, "angles_deg")
        if len(cop) != len(y):
            raise PerceptionError(f"cop_xy has {len(cop)} rows but angles_deg has {len(y)}")
        n_coef = len(self.powers_) + 1
        if len(cop) < n_coef:
            raise PerceptionError(
                f"order {self.order} has {n_coef} coefficients per angle; got only "
                f"{len(cop)} samples")
        if self.image_size is not None:
            w, h = self.image_size
            self.centre_px_ = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
            self.scale_px_ = max(w, h) / 2.0
        else:
            self.centre_px_ = cop.mean(axis=0)
            spread = float(cop.std(axis=0).max())
            self.scale_px_ = spread if spread > 0 else 1.0
        self.coef_ = np.zeros((2, len(self.powers_)))  # marks fitted for features()
        x = self.features(cop)
        design = np.hstack([np.ones((len(x), 1)), x])
        sol, _, rank, _ = np.linalg.lstsq(design, y, rcond=None)
        if rank < n_coef:
            self.coef_ = None
            raise PerceptionError(
                f"the CoPs do not determine an order-{self.order} polynomial (rank {rank} < "
                f"{n_coef}): they are collinear or too few distinct")
        self.intercept_ = sol[0].copy()
        self.coef_ = np.ascontiguousarray(sol[1:].T)
        return self

    def predict(self, cop_xy: np.ndarray, *, image_size: tuple[int, int] | None = None
                ) -> np.ndarray:
        """Predicted angles.

        Parameters
        ----------
        cop_xy : (n, 2) or (2,) float, px
        image_size : (w, h), optional
            See :meth:`features`.

        Returns
        -------
        angles_deg : (n, 2) float64, degrees
            Columns in ``angle_names`` order.
        """
        x = self.features(cop_xy, image_size=image_size)
        return x @ self.coef_.T + self.intercept_

    def score(self, cop_xy: np.ndarray, angles_deg: np.ndarray) -> RegressionScore:
        """R² per angle, overall R² (mean of the two) and RMSE per angle on a data set.

        Parameters
        ----------
        cop_xy : (n, 2) float, px
        angles_deg : (n, 2) float, degrees

        Returns
        -------
        RegressionScore
        """
        y = _as_2col(angles_deg, "angles_deg")
        pred = self.predict(cop_xy)
        if len(pred) != len(y):
            raise PerceptionError(f"cop_xy has {len(pred)} rows but angles_deg has {len(y)}")
        if len(y) < 2:
            raise PerceptionError("R² needs at least 2 samples")
        return score_predictions(y, pred, self.angle_names)

    # -- persistence ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready description of the fitted model."""
        self._check_fitted()
        return {
            "format": _FORMAT,
            "version": _FORMAT_VERSION,
            "order": self.order,
            "angle_names": list(self.angle_names),
            "input": "centre of pressure (x, y), px, OpenCV convention (pixel centres at "
                     "integer coordinates)",
            "image_size": None if self.image_size is None else list(self.image_size),
            "normalisation": {"centre_px": self.centre_px_.tolist(),
                              "scale_px": float(self.scale_px_),
                              "formula": "u = (x - centre_px[0]) / scale_px, "
                                         "v = (y - centre_px[1]) / scale_px"},
            "feature_names": list(self.feature_names_),
            "powers": self.powers_.tolist(),
            "coef": self.coef_.tolist(),
            "intercept": self.intercept_.tolist(),
        }

    def to_json(self, path: str | PathLike[str] | None = None) -> str:
        """Serialise to JSON (floats written with full precision); also write it to ``path``.

        Returns
        -------
        text : str
        """
        return model_json(self.to_dict(), path)

    @classmethod
    def from_dict(cls, data: dict) -> PoseRegressor:
        """Rebuild a fitted model from :meth:`to_dict` output."""
        try:
            if data.get("format") != _FORMAT:
                raise ModelError(f"not a {_FORMAT} model (format={data.get('format')!r})")
            if data.get("version") != _FORMAT_VERSION:
                raise ModelError(f"unsupported model version {data.get('version')!r}")
            model = cls(int(data["order"]), image_size=data["image_size"],
                        angle_names=tuple(data["angle_names"]))
            powers = np.asarray(data["powers"], dtype=np.int64)
            coef = np.asarray(data["coef"], dtype=np.float64)
            intercept = np.asarray(data["intercept"], dtype=np.float64)
            norm = data["normalisation"]
            centre = np.asarray(norm["centre_px"], dtype=np.float64)
            scale = float(norm["scale_px"])
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ModelError):
                raise
            raise ModelError(f"malformed model description: {exc!r}") from None
        n_feat = len(model.powers_)
        if not np.array_equal(powers, model.powers_):
            raise ModelError(f"powers do not match an order-{model.order} model")
        if coef.shape != (2, n_feat) or intercept.shape != (2,) or centre.shape != (2,):
            raise ModelError("coefficient, intercept or centre arrays have the wrong shape")
        values = np.concatenate([coef.ravel(), intercept, centre, [scale]])
        if not np.isfinite(values).all() or scale <= 0:
            raise ModelError("model contains non-finite numbers or a non-positive scale")
        if list(data.get("feature_names") or []) != model.feature_names_:
            raise ModelError("feature names do not match the powers")
        model.coef_, model.intercept_ = coef, intercept
        model.centre_px_, model.scale_px_ = centre, scale
        return model

    @classmethod
    def from_json(cls, source: str | PathLike[str]) -> PoseRegressor:
        """Load a model from a JSON string or a ``.json`` file path.

        Raises
        ------
        ModelError
            Malformed JSON or model; the message names the file when loading from a path.
        """
        text = str(source)
        is_path = isinstance(source, PathLike) or not text.lstrip().startswith("{")
        if is_path:
            try:
                text = Path(source).read_text(encoding="utf-8")
            except OSError as exc:
                raise ModelError(f"cannot read model file {str(source)!r}: {exc}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            where = f" in {str(source)!r}" if is_path else ""
            raise ModelError(f"invalid JSON{where}: {exc}") from None
        if not isinstance(data, dict):
            raise ModelError("model JSON must be an object")
        return cls.from_dict(data)

    def _check_fitted(self) -> None:
        if self.coef_ is None:
            raise ModelError("PoseRegressor is not fitted: call fit() or load a model first")

    def __repr__(self) -> str:
        state = "fitted" if self.coef_ is not None else "unfitted"
        return f"PoseRegressor(order={self.order}, image_size={self.image_size}, {state})"


def _check_size(image_size: tuple[int, int]) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise PerceptionError(f"image_size={image_size!r} must be (width, height)") from None
    if w < 1 or h < 1:
        raise PerceptionError(f"image_size={image_size!r} must be positive (width, height)")
    return w, h


def average_frames(values: np.ndarray, *, min_valid_fraction: float = 0.5) -> np.ndarray:
    """Average a feature over the frames of one sample, ignoring unreliable (NaN) frames.

    The seed protocol records about 3 s (60 frames) per pose and averages the CoP over them.

    Parameters
    ----------
    values : (n_frames, d) or (n_frames,) float
        Per-frame features (e.g. CoPs, px); NaN rows are frames to leave out.
    min_valid_fraction : float, (0, 1]
        Fewer valid frames than this fraction gives NaN instead of an average of too little.

    Returns
    -------
    mean : (d,) float64 (or a 0-d array for 1-D input)
    """
    if not 0 < min_valid_fraction <= 1:
        raise PerceptionError(f"min_valid_fraction={min_valid_fraction} must be in (0, 1]")
    v = np.asarray(values, dtype=np.float64)
    if v.ndim not in (1, 2) or len(v) == 0:
        raise PerceptionError(f"values must be a non-empty (n_frames, d) array, got {v.shape}")
    rows = v.reshape(len(v), -1)
    valid = np.isfinite(rows).all(axis=1)
    shape = v.shape[1:]
    if valid.sum() < min_valid_fraction * len(v) or not valid.any():
        return np.full(shape, np.nan)
    return rows[valid].mean(axis=0).reshape(shape)
