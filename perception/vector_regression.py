"""Pose regression from a feature vector of any length (e.g. :mod:`perception.flow`) to roll
and pitch, by polynomial least squares.

The same model as :class:`perception.PoseRegressor` (a multivariate polynomial of order 1-3,
ordinary least squares, one output per angle) for d inputs instead of the two CoP
coordinates. Inputs named in ``linear_inputs`` enter at degree 1 only (no powers, no
products): the polynomial spans the other inputs, and each linear input adds one term. Inputs
named in ``unused_inputs`` get no term: the model reads the same feature vector but leaves
them out (e.g. an input that its training data showed not to help). Each
input is standardised with the training mean and standard deviation
(``z_k = (x_k - mean_k) / std_k``) before the monomials are formed, so that inputs in px and
in px/px enter on one scale and the design matrix stays well conditioned. A saved model is
plain JSON, as for :class:`~perception.PoseRegressor`.
"""

from __future__ import annotations

from itertools import combinations_with_replacement
from os import PathLike

import numpy as np

from .errors import ModelError, PerceptionError
from .regression import RegressionScore, _check_size, model_json, score_predictions

__all__ = ["VectorRegressor", "loo_residuals", "monomials", "structured_powers", "vector_powers"]

_FORMAT = "perception.VectorRegressor"
_FORMAT_VERSION = 1


def vector_powers(order: int, n_inputs: int) -> np.ndarray:
    """(n_features, n_inputs) int: exponents of the monomials of degree 1..order, in
    scikit-learn's ``PolynomialFeatures`` order (degree by degree, lexicographic)."""
    rows = []
    for degree in range(1, order + 1):
        for combo in combinations_with_replacement(range(n_inputs), degree):
            rows.append(np.bincount(combo, minlength=n_inputs))
    return np.array(rows, dtype=np.int64).reshape(-1, n_inputs)


def structured_powers(order: int, n_inputs: int, linear: tuple[int, ...] = (),
                      unused: tuple[int, ...] = ()) -> np.ndarray:
    """(n_features, n_inputs) int: the monomials of degree 1..order of the inputs in neither
    ``linear`` nor ``unused`` (:func:`vector_powers`' order), then degree 1 of each input in
    ``linear`` (in the order given); inputs in ``unused`` appear in no monomial. With both
    empty it is :func:`vector_powers`."""
    poly = [k for k in range(n_inputs) if k not in linear and k not in unused]
    rows = np.zeros((0, n_inputs), dtype=np.int64)
    if poly:
        sub = vector_powers(order, len(poly))
        rows = np.zeros((len(sub), n_inputs), dtype=np.int64)
        rows[:, poly] = sub
    unit = np.eye(n_inputs, dtype=np.int64)[list(linear)]
    return np.vstack([rows, unit])


def monomials(z: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """(n, n_features): the monomials ``prod_k z_k ** powers[f, k]`` of the rows of ``z``
    (n, d), for exponents ``powers`` (n_features, d) from :func:`vector_powers`."""
    return np.prod(z[:, None, :] ** powers[None], axis=2)


def loo_residuals(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Leave-one-out residuals of the least-squares fit of ``y`` (n,) or (n, k) on the design
    ``a`` (n, p): each row's residual when the fit leaves that row out, ``e_i / (1 - h_ii)``
    from the hat matrix (exact for least squares, no refit). Columns that repeat one another
    (a rank-deficient design) are fitted on the span they have."""
    u, sv, _ = np.linalg.svd(a, full_matrices=False)
    q = u[:, sv > sv[0] * len(a) * np.finfo(float).eps]  # the columns' span, rank-revealing
    hat = np.einsum("ij,ij->i", q, q)
    resid = y - q @ (q.T @ y)
    scale = np.maximum(1.0 - hat, 1e-12)
    return resid / (scale if resid.ndim == 1 else scale[:, None])


class VectorRegressor:
    """Polynomial regression from d features to two angles (roll, pitch).

    Parameters
    ----------
    order : {1, 2, 3}
    input_names : sequence of str
        One name per input (d >= 1), saved with the model and checked when loading.
    image_size : (w, h), px, optional
        The frame format the features were measured on (recorded, checked by the caller).
    angle_names : (2,) str
    linear_inputs : sequence of str, optional
        Inputs (by name) that enter at degree 1 only; the polynomial of ``order`` spans the
        others (default: none, the full polynomial in every input).
    unused_inputs : sequence of str, optional
        Inputs (by name) given no term at all (default: none). They stay in ``input_names``,
        so the model takes the same feature vector as one that uses them.

    Attributes
    ----------
    coef_ : (2, n_features) float64, degrees per standardised unit^k
    intercept_ : (2,) float64, degrees
    mean_, std_ : (d,) float64
        Standardisation of the inputs (training mean, standard deviation; 1 where constant).
    powers_ : (n_features, d) int
    """

    def __init__(self, order: int = 2, *, input_names: tuple[str, ...] | list[str],
                 image_size: tuple[int, int] | None = None,
                 angle_names: tuple[str, str] = ("roll_deg", "pitch_deg"),
                 linear_inputs: tuple[str, ...] | list[str] = (),
                 unused_inputs: tuple[str, ...] | list[str] = ()) -> None:
        if isinstance(order, bool) or order not in (1, 2, 3):
            raise PerceptionError(f"order={order!r} must be 1, 2 or 3")
        names = tuple(str(n) for n in input_names)
        if not names:
            raise PerceptionError("input_names must name at least one input")
        self.order = int(order)
        self.input_names = names
        self.image_size = None if image_size is None else _check_size(image_size)
        self.angle_names = (str(angle_names[0]), str(angle_names[1]))
        linear = tuple(str(n) for n in linear_inputs)
        unknown = [n for n in linear if n not in names]
        if unknown or len(set(linear)) != len(linear):
            raise PerceptionError(f"linear_inputs={list(linear)!r} must name distinct inputs "
                                  f"among input_names ({', '.join(names)})")
        self.linear_inputs = linear
        unused = tuple(str(n) for n in unused_inputs)
        bad = [n for n in unused if n not in names or n in linear]
        if bad or len(set(unused)) != len(unused) or len(unused) == len(names):
            raise PerceptionError(f"unused_inputs={list(unused)!r} must name distinct inputs "
                                  f"among input_names ({', '.join(names)}), none of them in "
                                  "linear_inputs, and leave at least one input used")
        self.unused_inputs = unused
        self.powers_ = structured_powers(self.order, len(names),
                                         tuple(names.index(n) for n in linear),
                                         tuple(names.index(n) for n in unused))
        self.coef_: np.ndarray | None = None
        self.intercept_: np.ndarray | None = None
        self.mean_: np.ndarray | None = None
        self.std_: np.ndarray | None = None

    @property
    def n_inputs(self) -> int:
        return len(self.input_names)

    def _inputs(self, x: np.ndarray) -> np.ndarray:
        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 1 and arr.shape == (self.n_inputs,):
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.n_inputs:
            raise PerceptionError(f"features must have shape (n, {self.n_inputs}) "
                                  f"({', '.join(self.input_names)}), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise PerceptionError("features contain NaN or inf (drop unreliable frames first)")
        return arr

    def design(self, x: np.ndarray) -> np.ndarray:
        """(n, n_features) monomials of the standardised inputs (no constant column)."""
        if self.mean_ is None:
            raise ModelError("VectorRegressor is not fitted: call fit() or load a model first")
        z = (self._inputs(x) - self.mean_) / self.std_
        return monomials(z, self.powers_)

    def fit(self, x: np.ndarray, angles_deg: np.ndarray) -> VectorRegressor:
        """Least-squares fit.

        Parameters
        ----------
        x : (n, d) float
        angles_deg : (n, 2) float, degrees

        Raises
        ------
        PerceptionError
            Too few samples, or inputs that do not determine the polynomial (rank deficient).
        """
        xs = self._inputs(x)
        y = np.asarray(angles_deg, dtype=np.float64)
        if y.shape != (len(xs), 2) or not np.isfinite(y).all():
            raise PerceptionError(f"angles_deg must be finite with shape ({len(xs)}, 2), got "
                                  f"{y.shape}")
        n_coef = len(self.powers_) + 1
        if len(xs) < n_coef:
            raise PerceptionError(f"{len(xs)} samples cannot fit an order-{self.order} model "
                                  f"of {self.n_inputs} inputs ({n_coef} coefficients)")
        self.mean_ = xs.mean(axis=0)
        sd = xs.std(axis=0)
        self.std_ = np.where(sd > 0, sd, 1.0)
        a = np.hstack([np.ones((len(xs), 1)), self.design(xs)])
        sol, _, rank, _ = np.linalg.lstsq(a, y, rcond=None)
        if rank < n_coef:
            self.mean_ = self.std_ = None
            raise PerceptionError(f"the features do not determine an order-{self.order} "
                                  f"polynomial (rank {rank} < {n_coef})")
        self.intercept_ = sol[0].copy()
        self.coef_ = np.ascontiguousarray(sol[1:].T)
        return self

    def loo_mse(self, x: np.ndarray, angles_deg: np.ndarray) -> float:
        """Mean squared leave-one-out error (deg², both angles) of this model's form on
        ``(x, angles_deg)``: what it would miss on a sample it was not fitted on
        (:func:`loo_residuals`; standardised with all rows, as :meth:`fit` does). Fits the
        model on every row as a side effect."""
        self.fit(x, angles_deg)
        a = np.hstack([np.ones((len(x), 1)), self.design(x)])
        return float(np.mean(loo_residuals(a, np.asarray(angles_deg, dtype=np.float64)) ** 2))

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(n, 2) predicted angles, degrees."""
        self._check_fitted()
        return self.design(x) @ self.coef_.T + self.intercept_

    def score(self, x: np.ndarray, angles_deg: np.ndarray) -> RegressionScore:
        """R² and RMSE per angle (as :meth:`perception.PoseRegressor.score`)."""
        y = np.asarray(angles_deg, dtype=np.float64)
        pred = self.predict(x)
        if y.shape != pred.shape or len(y) < 2:
            raise PerceptionError(f"angles_deg must have shape {pred.shape} (at least 2 rows)")
        return score_predictions(y, pred, self.angle_names)

    # -- persistence ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        self._check_fitted()
        return {"format": _FORMAT, "version": _FORMAT_VERSION, "order": self.order,
                "angle_names": list(self.angle_names), "input_names": list(self.input_names),
                "image_size": None if self.image_size is None else list(self.image_size),
                "linear_inputs": list(self.linear_inputs),
                "unused_inputs": list(self.unused_inputs),
                "normalisation": {"mean": self.mean_.tolist(), "std": self.std_.tolist(),
                                  "formula": "z_k = (x_k - mean[k]) / std[k]"},
                "powers": self.powers_.tolist(), "coef": self.coef_.tolist(),
                "intercept": self.intercept_.tolist()}

    def to_json(self, path: str | PathLike[str] | None = None) -> str:
        return model_json(self.to_dict(), path)

    @classmethod
    def from_dict(cls, data: dict) -> VectorRegressor:
        """Rebuild a fitted model from :meth:`to_dict` output (checked)."""
        if data.get("format") != _FORMAT:
            raise ModelError(f"not a {_FORMAT} model (format={data.get('format')!r})")
        if data.get("version") != _FORMAT_VERSION:
            raise ModelError(f"unsupported model version {data.get('version')!r}")
        try:
            model = cls(int(data["order"]), input_names=data["input_names"],
                        image_size=data["image_size"], angle_names=tuple(data["angle_names"]),
                        linear_inputs=data.get("linear_inputs", ()),
                        unused_inputs=data.get("unused_inputs", ()))
            powers = np.asarray(data["powers"], dtype=np.int64)
            coef = np.asarray(data["coef"], dtype=np.float64)
            intercept = np.asarray(data["intercept"], dtype=np.float64)
            mean = np.asarray(data["normalisation"]["mean"], dtype=np.float64)
            std = np.asarray(data["normalisation"]["std"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"malformed model description: {exc!r}") from None
        d, nf = model.n_inputs, len(model.powers_)
        if not np.array_equal(powers, model.powers_):
            raise ModelError(f"powers do not match an order-{model.order} model of {d} inputs "
                             f"(linear in {list(model.linear_inputs)}, unused "
                             f"{list(model.unused_inputs)})")
        if coef.shape != (2, nf) or intercept.shape != (2,) or mean.shape != (d,) \
                or std.shape != (d,):
            raise ModelError("coefficient, intercept or normalisation arrays have the wrong "
                             "shape")
        values = np.concatenate([coef.ravel(), intercept, mean, std])
        if not np.isfinite(values).all() or (std <= 0).any():
            raise ModelError("model contains non-finite numbers or a non-positive std")
        model.coef_, model.intercept_, model.mean_, model.std_ = coef, intercept, mean, std
        return model

    def _check_fitted(self) -> None:
        if self.coef_ is None:
            raise ModelError("VectorRegressor is not fitted: call fit() or load a model first")

    def __repr__(self) -> str:
        state = "fitted" if self.coef_ is not None else "unfitted"
        return (f"VectorRegressor(order={self.order}, inputs={self.n_inputs}, "
                f"linear={len(self.linear_inputs)}, unused={len(self.unused_inputs)}, "
                f"image_size={self.image_size}, {state})")
