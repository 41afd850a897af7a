"""Pose regression: exact recovery, honest R², JSON round trip without scikit-learn."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from sklearn.metrics import mean_squared_error, r2_score

import perception as pc
from perception.regression import polynomial_powers

W, H = 640, 480


def _uv(cop):
    """The documented normalisation for image_size=(640, 480)."""
    return (cop - [(W - 1) / 2, (H - 1) / 2]) / (max(W, H) / 2)


def _poly(uv, powers, coef, intercept):
    feats = np.stack([uv[:, 0] ** pu * uv[:, 1] ** pv for pu, pv in powers], axis=1)
    return feats @ coef.T + intercept


def test_powers_follow_sklearn_order():
    assert polynomial_powers(2).tolist() == [[1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]
    assert pc.PoseRegressor(3).feature_names_ == [
        "u", "v", "u^2", "u v", "v^2", "u^3", "u^2 v", "u v^2", "v^3"]


@pytest.mark.parametrize("order", [1, 2, 3])
def test_recovers_known_coefficients_exactly(order):
    rng = np.random.default_rng(order)
    powers = polynomial_powers(order)
    coef = rng.uniform(-20, 20, (2, len(powers)))
    intercept = rng.uniform(-5, 5, 2)
    cop = rng.uniform((200, 150), (440, 330), (60, 2))
    angles = _poly(_uv(cop), powers, coef, intercept)
    model = pc.PoseRegressor(order, image_size=(W, H)).fit(cop, angles)
    assert np.allclose(model.coef_, coef, rtol=0, atol=1e-9)
    assert np.allclose(model.intercept_, intercept, rtol=0, atol=1e-9)
    score = model.score(cop, angles)
    assert np.allclose(score.r2, 1.0, atol=1e-12) and score.r2_overall == pytest.approx(1.0)
    assert (score.rmse_deg < 1e-9).all()


def test_score_definitions():
    rng = np.random.default_rng(7)
    cop = rng.uniform((200, 150), (440, 330), (80, 2))
    truth = np.stack([0.05 * (cop[:, 0] - 320), -0.04 * (cop[:, 1] - 240)], axis=1)
    angles = truth + rng.normal(0, 0.5, truth.shape)
    model = pc.PoseRegressor(1, image_size=(W, H)).fit(cop, angles)
    pred = model.predict(cop)
    # scikit-learn's metrics as the independent reference
    r2 = r2_score(angles, pred, multioutput="raw_values")
    s = model.score(cop, angles)
    assert np.allclose(s.r2, r2, rtol=1e-12, atol=0)
    assert s.r2_overall == pytest.approx(r2_score(angles, pred), rel=1e-12)
    assert np.allclose(s.rmse_deg, np.sqrt(mean_squared_error(angles, pred,
                                                              multioutput="raw_values")))
    assert s.n == 80 and s.angle_names == ("roll_deg", "pitch_deg")


def test_held_out_r2_is_honest():
    # noisy data from a smooth truth; fit on the middle of the pad, test outside it
    rng = np.random.default_rng(11)

    def truth(cop):
        uv = _uv(cop)
        return np.stack([16 * uv[:, 0] + 3 * uv[:, 0] * uv[:, 1],
                         -11 * uv[:, 1] + 4 * uv[:, 0] ** 2], axis=1)

    train = rng.uniform((260, 190), (380, 290), (40, 2))
    test = rng.uniform((200, 150), (440, 330), (200, 2))
    test = test[(np.abs(test[:, 0] - 320) > 60) | (np.abs(test[:, 1] - 240) > 50)]
    y_train = truth(train) + rng.normal(0, 1.0, (len(train), 2))
    y_test = truth(test) + rng.normal(0, 1.0, (len(test), 2))
    model = pc.PoseRegressor(3, image_size=(W, H)).fit(train, y_train)
    r2_train = model.score(train, y_train).r2_overall
    r2_test = model.score(test, y_test).r2_overall
    assert r2_test < r2_train  # extrapolating a 3rd-order fit of noisy data is worse
    # and a 1st-order model generalises better than the 3rd-order one here
    lin = pc.PoseRegressor(1, image_size=(W, H)).fit(train, y_train)
    assert lin.score(test, y_test).r2_overall > r2_test


def test_same_answer_as_sklearn():
    from sklearn.linear_model import LinearRegression
    from sklearn.preprocessing import PolynomialFeatures

    rng = np.random.default_rng(3)
    cop = rng.uniform((200, 150), (440, 330), (100, 2))
    angles = rng.normal(0, 5, (100, 2)) + 0.1 * cop
    ours = pc.PoseRegressor(3, image_size=(W, H)).fit(cop, angles)
    feats = PolynomialFeatures(3, include_bias=False)
    ref = LinearRegression().fit(feats.fit_transform(_uv(cop)), angles)
    assert np.allclose(ours.predict(cop), ref.predict(feats.transform(_uv(cop))), atol=1e-8)
    assert np.allclose(ours.coef_, ref.coef_, atol=1e-7)


@pytest.mark.parametrize("image_size", [(W, H), None])
def test_json_round_trip_identical_predictions(tmp_path, image_size):
    rng = np.random.default_rng(5)
    cop = rng.uniform((200, 150), (440, 330), (50, 2))
    angles = rng.normal(0, 5, (50, 2))
    model = pc.PoseRegressor(2, image_size=image_size).fit(cop, angles)
    text = model.to_json()
    data = json.loads(text)
    assert data["feature_names"] == model.feature_names_
    assert data["image_size"] == (None if image_size is None else list(image_size))
    loaded = pc.PoseRegressor.from_json(text)
    probe = rng.uniform((0, 0), (W, H), (30, 2))
    assert np.array_equal(loaded.predict(probe), model.predict(probe))
    path = tmp_path / "model.json"
    model.to_json(path)
    assert np.array_equal(pc.PoseRegressor.from_json(path).predict(probe), model.predict(probe))


def test_loading_needs_no_sklearn(monkeypatch):
    rng = np.random.default_rng(6)
    cop = rng.uniform((200, 150), (440, 330), (30, 2))
    model = pc.PoseRegressor(2).fit(cop, rng.normal(0, 5, (30, 2)))
    text = model.to_json()
    monkeypatch.setitem(sys.modules, "sklearn", None)  # any sklearn import now fails
    assert np.array_equal(pc.PoseRegressor.from_json(text).predict(cop), model.predict(cop))


def test_model_applies_to_another_image_size():
    rng = np.random.default_rng(8)
    cop = rng.uniform((200, 150), (440, 330), (40, 2))
    model = pc.PoseRegressor(2, image_size=(W, H)).fit(cop, rng.normal(0, 5, (40, 2)))
    # the same CoPs measured on a 1280x960 rig (twice the pixels along each axis)
    assert np.allclose(model.predict(cop * 2, image_size=(2 * W, 2 * H)), model.predict(cop),
                       atol=1e-12)


def test_average_frames():
    cops = np.array([[1.0, 2.0], [3.0, 4.0], [np.nan, np.nan], [5.0, 6.0]])
    assert np.allclose(pc.average_frames(cops), [3.0, 4.0])
    assert np.isnan(pc.average_frames(cops, min_valid_fraction=1.0)).all()
    assert pc.average_frames(np.array([1.0, 2.0, np.nan])) == pytest.approx(1.5)
    with pytest.raises(pc.PerceptionError):
        pc.average_frames(np.zeros((0, 2)))


def test_errors():
    with pytest.raises(pc.PerceptionError, match="order"):
        pc.PoseRegressor(4)
    model = pc.PoseRegressor(2)
    with pytest.raises(pc.ModelError, match="not fitted"):
        model.predict(np.zeros((1, 2)))
    with pytest.raises(pc.PerceptionError, match="samples"):
        model.fit(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(pc.PerceptionError, match="NaN"):
        model.fit(np.full((10, 2), np.nan), np.zeros((10, 2)))
    collinear = np.stack([np.linspace(0, 100, 20), np.linspace(0, 100, 20)], axis=1)
    with pytest.raises(pc.PerceptionError, match="rank"):
        model.fit(collinear, np.zeros((20, 2)))
    with pytest.raises(pc.ModelError, match="invalid JSON"):
        pc.PoseRegressor.from_json("{not json")
    with pytest.raises(pc.ModelError, match="format"):
        pc.PoseRegressor.from_json('{"format": "something else"}')
    with pytest.raises(pc.ModelError, match="cannot read"):
        pc.PoseRegressor.from_json("/nonexistent/model.json")
