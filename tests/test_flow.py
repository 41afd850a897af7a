"""The whole-array motion feature (perception/flow.py), the polynomial regressor of a feature
vector (perception/vector_regression.py) and the choice of feature and order by (nested)
cross-validation (tactip_lab/fitting/cv_select.py): known answers on synthetic marker arrays, a
second
implementation (scikit-learn) for the regression, a planted informative feature for the choice."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import perception as pc
from perception.errors import ModelError, PerceptionError, PointsError
from perception.flow import FLOW_NAMES, flow_features
from perception.vector_regression import VectorRegressor
from tactip_lab.fitting.bristol import FrameTable, cross_validate
from tactip_lab.fitting.cv_select import nested_cv, select_by_cv
from tactip_lab.fitting.fit import FeatureTable

REST = pc.hex_lattice(61, 12.0, (64.0, 64.0))
NO_COP = np.array([np.nan, np.nan])


def _flow(points, rest=REST, cop=NO_COP):
    return dict(zip(FLOW_NAMES, flow_features(points, rest, cop), strict=True))


def test_a_rigid_shift_gives_its_vector_as_the_mean_displacement_and_no_gradient():
    f = _flow(REST + (2.25, -0.75), cop=np.array([60.0, 70.0]))
    assert (f["cop_x"], f["cop_y"]) == (60.0, 70.0)
    assert f["mean_dx"] == pytest.approx(2.25, abs=1e-12)
    assert f["mean_dy"] == pytest.approx(-0.75, abs=1e-12)
    # every marker moved equally: the displacement-weighted centroid is the array's centroid
    assert f["wc_x"] == pytest.approx(REST[:, 0].mean(), abs=1e-9)
    assert f["wc_y"] == pytest.approx(REST[:, 1].mean(), abs=1e-9)
    for k in ("j_xx", "j_xy", "j_yx", "j_yy"):
        assert f[k] == pytest.approx(0.0, abs=1e-12)


def test_an_affine_motion_gives_its_matrix_as_the_gradient():
    # points = rest + t + A (rest - c): a 2 % stretch in x, 1 % compression in y, a shear,
    # and a small rotation; the entries are chosen here, not by the code
    a = np.array([[0.02, 0.015], [-0.01, -0.01]])
    t = np.array([0.4, -1.1])
    c = REST.mean(axis=0)
    f = _flow(REST + t + (REST - c) @ a.T)
    assert f["mean_dx"] == pytest.approx(t[0], abs=1e-12)
    assert f["mean_dy"] == pytest.approx(t[1], abs=1e-12)
    np.testing.assert_allclose([f["j_xx"], f["j_xy"], f["j_yx"], f["j_yy"]], a.ravel(),
                               atol=1e-12)


def test_the_weighted_centroid_sits_where_the_array_moved():
    pts = REST.copy()
    pts[5] += (3.0, 4.0)  # one marker moved by 5 px
    pts[40] += (0.0, -5.0)  # another by 5 px
    f = _flow(pts)
    expected = 0.5 * (REST[5] + REST[40])
    assert (f["wc_x"], f["wc_y"]) == pytest.approx(tuple(expected), abs=1e-12)
    assert f["mean_dx"] == pytest.approx(3.0 / len(REST), abs=1e-12)
    assert f["mean_dy"] == pytest.approx(-1.0 / len(REST), abs=1e-12)


def test_lost_markers_are_left_out_and_nothing_tracked_gives_nan():
    pts = REST + (1.0, 2.0)
    pts[:10] = (500.0, 500.0)  # garbage on the markers that will be marked lost
    lost = pts.copy()
    lost[:10] = np.nan
    f = _flow(lost)
    assert (f["mean_dx"], f["mean_dy"]) == pytest.approx((1.0, 2.0), abs=1e-12)
    assert f["wc_x"] == pytest.approx(REST[10:, 0].mean(), abs=1e-9)
    none = flow_features(np.full_like(REST, np.nan), REST, NO_COP)
    assert np.isnan(none).all()
    still = _flow(REST)  # nothing moved: no weighted centroid, a zero gradient
    assert np.isnan(still["wc_x"]) and still["j_xx"] == 0.0
    two = np.full_like(REST, np.nan)
    two[:2] = REST[:2] + 1.0  # two markers cannot determine a gradient
    f2 = _flow(two)
    assert f2["mean_dx"] == pytest.approx(1.0) and np.isnan(f2["j_xx"])


def test_flow_rejects_mismatched_arrays():
    with pytest.raises(PointsError, match="one row per rest marker"):
        flow_features(REST[:-1], REST, NO_COP)
    with pytest.raises(PointsError, match="cop_growth must have shape"):
        flow_features(REST, REST, np.zeros(3))


def test_the_pipeline_reports_the_flow_of_a_shifted_array():
    from perception.synthetic import render_markers

    rest_pts = pc.hex_lattice(61, 26.0, (320.0, 240.0))
    rng = np.random.default_rng(0)
    rest = render_markers(rest_pts, diameter_px=11.0, noise_sigma=0.01, rng=rng).image
    moved = render_markers(rest_pts + (3.0, -2.0), diameter_px=11.0, noise_sigma=0.01,
                           rng=rng).image
    pipe = pc.FeaturePipeline(rest)
    f = dict(zip(FLOW_NAMES, pipe.process(moved).flow, strict=True))
    # sub-pixel centroids of rendered discs: the shift is recovered to a few hundredths
    assert (f["mean_dx"], f["mean_dy"]) == pytest.approx((3.0, -2.0), abs=0.05)
    assert abs(f["j_xx"]) < 2e-3 and abs(f["j_yy"]) < 2e-3


# ---------------------------------------------------------------------------------------------
# VectorRegressor


def _poly_data(n, rng):
    x = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(10, 30, n), rng.normal(0, 0.01, n)])
    roll = 2.0 * x[:, 0] - 0.5 * x[:, 1] + 300.0 * x[:, 2] + 0.25 * x[:, 0] * x[:, 1]
    pitch = -1.5 * x[:, 1] + 0.1 * x[:, 1] ** 2 + 4.0
    return x, np.column_stack([roll, pitch])


def test_vector_regressor_recovers_an_exact_polynomial_and_round_trips_json(tmp_path):
    rng = np.random.default_rng(1)
    x, y = _poly_data(80, rng)
    m = VectorRegressor(2, input_names=("a", "b", "c"), image_size=(128, 128)).fit(x, y)
    xt, yt = _poly_data(20, rng)
    np.testing.assert_allclose(m.predict(xt), yt, atol=1e-8)
    path = tmp_path / "m.json"
    m.to_json(path)
    import json

    back = VectorRegressor.from_dict(json.loads(path.read_text()))
    np.testing.assert_allclose(back.predict(xt), m.predict(xt), rtol=0, atol=1e-12)
    assert back.image_size == (128, 128) and back.input_names == ("a", "b", "c")
    # an order-1 model cannot represent the products: it must not fit them exactly
    lin = VectorRegressor(1, input_names=("a", "b", "c")).fit(x, y)
    assert np.abs(lin.predict(xt) - yt).max() > 0.1


def test_vector_regressor_matches_scikit_learn_on_noisy_data():
    from sklearn.linear_model import LinearRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import PolynomialFeatures, StandardScaler

    rng = np.random.default_rng(2)
    x, y = _poly_data(120, rng)
    y = y + rng.normal(0, 0.3, y.shape)
    for order in (1, 2, 3):
        ours = VectorRegressor(order, input_names=("a", "b", "c")).fit(x, y)
        # the same model space; scikit-learn standardises by its own code (raw cubes of inputs
        # 0.01 and 30 apart in scale would make its least squares ill-conditioned)
        ref = make_pipeline(StandardScaler(), PolynomialFeatures(order, include_bias=False),
                            LinearRegression()).fit(x, y)
        xt, _ = _poly_data(15, rng)
        np.testing.assert_allclose(ours.predict(xt), ref.predict(xt), atol=1e-6)


def _partly_linear(n, rng, square=0.0):
    """Angles that are a quadratic in inputs a, b and linear in c and d (plus ``square`` times
    c², which a model linear in c cannot represent)."""
    x = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(10, 30, n), rng.normal(0, 2, n),
                         rng.normal(5, 1, n)])
    roll = 1.5 * x[:, 0] * x[:, 1] - 0.2 * x[:, 1] ** 2 + 3.0 * x[:, 2] - 2.0 * x[:, 3]
    pitch = 0.5 * x[:, 0] ** 2 + 7.0 * x[:, 3] + 1.0 + square * x[:, 2] ** 2
    return x, np.column_stack([roll, pitch])


def test_linear_inputs_enter_at_degree_one_only(tmp_path):
    import json

    rng = np.random.default_rng(5)
    names = ("a", "b", "c", "d")
    m = VectorRegressor(2, input_names=names, linear_inputs=("c", "d"))
    # a quadratic in two inputs has 5 monomials; each linear input adds one: 7 (+ the constant)
    assert len(m.powers_) == 7
    x, y = _partly_linear(60, rng)
    m.fit(x, y)
    xt, yt = _partly_linear(20, rng)
    np.testing.assert_allclose(m.predict(xt), yt, atol=1e-8)
    back = VectorRegressor.from_dict(json.loads(m.to_json()))
    assert back.linear_inputs == ("c", "d")
    np.testing.assert_allclose(back.predict(xt), m.predict(xt), rtol=0, atol=1e-12)
    # c², c·a and the like are not in the model: a curved answer in c is not fitted exactly,
    # while the full quadratic in every input fits it
    x2, y2 = _partly_linear(60, rng, square=0.8)
    xt2, yt2 = _partly_linear(20, rng, square=0.8)
    part = VectorRegressor(2, input_names=names, linear_inputs=("c", "d")).fit(x2, y2)
    full = VectorRegressor(2, input_names=names).fit(x2, y2)
    assert np.abs(part.predict(xt2) - yt2).max() > 0.5
    np.testing.assert_allclose(full.predict(xt2), yt2, atol=1e-8)
    # the same model as scikit-learn's least squares on the same columns (a second method)
    from sklearn.linear_model import LinearRegression

    z = (x - x.mean(axis=0)) / x.std(axis=0)
    cols = np.column_stack([z[:, 0], z[:, 1], z[:, 0] ** 2, z[:, 0] * z[:, 1], z[:, 1] ** 2,
                            z[:, 2], z[:, 3]])
    noisy = y + rng.normal(0, 0.5, y.shape)
    ref = LinearRegression().fit(cols, noisy)
    ours = VectorRegressor(2, input_names=names, linear_inputs=("c", "d")).fit(x, noisy)
    zt = (xt - x.mean(axis=0)) / x.std(axis=0)
    colt = np.column_stack([zt[:, 0], zt[:, 1], zt[:, 0] ** 2, zt[:, 0] * zt[:, 1],
                            zt[:, 1] ** 2, zt[:, 2], zt[:, 3]])
    np.testing.assert_allclose(ours.predict(xt), ref.predict(colt), atol=1e-8)
    with pytest.raises(PerceptionError, match="linear_inputs"):
        VectorRegressor(2, input_names=names, linear_inputs=("e",))
    with pytest.raises(PerceptionError, match="linear_inputs"):
        VectorRegressor(2, input_names=names, linear_inputs=("c", "c"))


def test_unused_inputs_get_no_term_and_leave_one_out_is_a_refit_without_each_sample(tmp_path):
    import json

    rng = np.random.default_rng(17)
    names = ("a", "b", "c", "d")
    x, y = _partly_linear(50, rng)
    y = y + rng.normal(0, 0.3, y.shape)
    m = VectorRegressor(2, input_names=names, linear_inputs=("d",), unused_inputs=("c",))
    # a quadratic in a, b (5 monomials) and d linear: c appears in no monomial
    assert len(m.powers_) == 6 and not m.powers_[:, 2].any()
    m.fit(x, y)
    xt, _ = _partly_linear(10, rng)
    moved = xt.copy()
    moved[:, 2] += rng.normal(0, 50.0, len(xt))  # c changed wildly: the answer does not move
    np.testing.assert_allclose(m.predict(moved), m.predict(xt), rtol=0, atol=1e-12)
    back = VectorRegressor.from_dict(json.loads(m.to_json()))
    assert back.unused_inputs == ("c",) and back.input_names == names
    np.testing.assert_allclose(back.predict(xt), m.predict(xt), rtol=0, atol=1e-12)
    # the hat-matrix shortcut against the definition: refit without each sample (a second
    # method), mean squared miss over both angles
    misses = []
    for i in range(len(x)):
        keep = np.arange(len(x)) != i
        other = VectorRegressor(2, input_names=names, linear_inputs=("d",),
                                unused_inputs=("c",)).fit(x[keep], y[keep])
        misses.append(y[i] - other.predict(x[i:i + 1])[0])
    # standardisation: the shortcut standardises with every row, a refit without one; the
    # model (a polynomial with a constant) spans the same functions either way
    assert m.loo_mse(x, y) == pytest.approx(float(np.mean(np.square(misses))), rel=1e-9)
    for bad in (("e",), ("d",), ("c", "c"), names):
        with pytest.raises(PerceptionError, match="unused_inputs"):
            VectorRegressor(2, input_names=names, linear_inputs=("d",), unused_inputs=bad)
    with pytest.raises(PerceptionError, match="at least one input used"):
        VectorRegressor(2, input_names=("a", "b"), unused_inputs=("a", "b"))


def test_vector_regressor_errors_name_the_problem():
    m = VectorRegressor(2, input_names=("a", "b"))
    with pytest.raises(ModelError, match="not fitted"):
        m.predict(np.zeros((1, 2)))
    with pytest.raises(PerceptionError, match=r"shape \(n, 2\)"):
        m.fit(np.zeros((10, 3)), np.zeros((10, 2)))
    with pytest.raises(PerceptionError, match="cannot fit an order-2 model"):
        m.fit(np.ones((4, 2)), np.zeros((4, 2)))
    with pytest.raises(PerceptionError, match="NaN"):
        m.fit(np.full((10, 2), np.nan), np.zeros((10, 2)))
    with pytest.raises(PerceptionError, match="order=4"):
        VectorRegressor(4, input_names=("a",))
    with pytest.raises(ModelError, match="not a perception.VectorRegressor"):
        VectorRegressor.from_dict({"format": "perception.PoseRegressor"})


# ---------------------------------------------------------------------------------------------
# Choosing the feature and the order


def _frames(n, rng, *, flagged=()):
    """A FrameTable whose angles are linear in the flow feature's mean displacement (plus
    noise) while the growth CoP is pure noise, and the area CoP a noisy copy of the angles."""
    angles = rng.uniform(-15, 15, (n, 2))
    flow = rng.normal(0, 1, (n, len(FLOW_NAMES)))
    flow[:, 2] = 0.1 * angles[:, 0] + rng.normal(0, 0.02, n)
    flow[:, 3] = -0.07 * angles[:, 1] + rng.normal(0, 0.02, n)
    cop = {"growth": rng.uniform(0, 128, (n, 2)),
           "area": 64 + 2 * angles + rng.normal(0, 6, (n, 2)),
           "flow": flow}
    reliable = np.ones(n, bool)
    reliable[list(flagged)] = False
    return FrameTable(_Folder(angles), cop, np.full(n, 61), reliable, [""] * n, 61)


class _Folder(SimpleNamespace):
    def __init__(self, angles):
        super().__init__(angles_deg=angles, depth_mm=np.full(len(angles), 3.0),
                         image_size=(128, 128), root="synthetic")

    def __len__(self):
        return len(self.angles_deg)


def test_cv_chooses_the_informative_feature_and_nested_cv_scores_it_on_unseen_rows():
    rng = np.random.default_rng(5)
    frames = _frames(150, rng, flagged=(3, 77))
    best, cands = select_by_cv(frames, ["growth", "area", "flow"], [1, 2], 5)
    assert [(c["feature"], c["order"]) for c in cands] == [
        ("growth", 1), ("growth", 2), ("area", 1), ("area", 2), ("flow", 1), ("flow", 2)]
    assert best["feature"] == "flow" and best["order"] == 1
    assert all(c["n_used"] == 148 for c in cands)  # flagged rows are left out of every one
    growth = cands[0]
    assert growth["r2_roll"] < 0.1 and growth["r2_pitch"] < 0.1  # noise predicts nothing
    # the noise on the displacement is 0.02 px on slopes of 0.1 and 0.07 px/deg over a
    # uniform +-15 deg spread (sd 8.66 deg): R^2 = 1 - (0.2 deg)^2 / 75 and 1 - (0.286)^2 / 75
    assert best["r2_roll"] == pytest.approx(1 - 0.2 ** 2 / 75, abs=2e-3)
    assert best["r2_pitch"] == pytest.approx(1 - (0.02 / 0.07) ** 2 / 75, abs=3e-3)
    nested = nested_cv(frames, ["growth", "area", "flow"], [1, 2], 5)
    assert nested["n_predicted"] == 148
    assert np.isnan(nested["predicted_deg"][[3, 77]]).all()
    assert all(c.startswith("flow") for c in nested["chosen"])
    assert nested["r2_roll"] == pytest.approx(best["r2_roll"], abs=5e-3)


def test_cross_validation_of_a_vector_feature_matches_scikit_learn():
    from sklearn.linear_model import LinearRegression
    from sklearn.model_selection import PredefinedSplit, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import PolynomialFeatures

    rng = np.random.default_rng(6)
    frames = _frames(150, rng)
    t = frames.features("flow")
    assert isinstance(t, FeatureTable) and t.cop_px.shape == (150, len(FLOW_NAMES))
    ours = cross_validate(t, 2, 3, seed=9, feature="flow")
    fold = np.empty(150, int)
    perm = np.random.default_rng(9).permutation(150)
    for k in range(3):
        fold[perm[k::3]] = k
    ref = cross_val_predict(make_pipeline(PolynomialFeatures(2, include_bias=False),
                                          LinearRegression()), t.cop_px, t.angles_deg,
                            cv=PredefinedSplit(fold))
    np.testing.assert_allclose(ours["predicted_deg"], ref, atol=1e-6)


def test_a_search_margin_finds_rim_markers_pushed_beyond_the_region():
    from perception.synthetic import render_markers

    s = 26.0
    c = np.array([320.0, 240.0])
    rest_pts = pc.hex_lattice(61, s, c)
    r = np.linalg.norm(rest_pts - c, axis=1)
    rim = r > r.max() - 1.0  # the outer ring (hull corners and edges)
    pushed = rest_pts.copy()
    pushed[rim] += 0.8 * s * (rest_pts[rim] - c) / r[rim, None]  # 0.8 spacing outward: past
    # the region's edge (the hull grown by 0.5 spacing), within a one-spacing gate
    rng = np.random.default_rng(4)
    rest = render_markers(rest_pts, diameter_px=11.0, noise_sigma=0.01, rng=rng).image
    frame = render_markers(pushed, diameter_px=11.0, noise_sigma=0.01, rng=rng).image
    tracking = pc.TrackingParams(gate_fraction=1.0, use_velocity=False)
    plain = pc.FeaturePipeline(rest, tracking=tracking)
    assert plain.search_region is plain.region
    f0 = plain.process(frame)
    assert f0.n_lost >= rim.sum() - 6  # the corners' cells reach further: a few may be found
    wide = pc.FeaturePipeline(rest, tracking=tracking, search_margin_px=0.5 * s)
    f1 = wide.process(frame)
    assert f1.n_lost == 0
    # the tracks are in the rest detection's order: pair them with the lattice by rest position
    from scipy.spatial import cKDTree

    dist, k = cKDTree(rest_pts).query(wide.rest_points)
    assert dist.max() < 0.1
    np.testing.assert_allclose(f1.points, pushed[k], atol=0.1)
    with pytest.raises(PerceptionError, match="search_margin_px=-1"):
        pc.FeaturePipeline(rest, search_margin_px=-1)


def test_a_grown_marker_is_a_merged_pair_only_if_its_partner_is_missing():
    rest = pc.hex_lattice(37, 10.0, (50.0, 50.0))
    areas = np.full(len(rest), 6.0)  # a 128x128 frame's 2-3 px markers
    params = pc.TrackingParams(gate_fraction=1.0, use_velocity=False,
                               merge_needs_lost_neighbour=True)
    # marker 0 grew to 2.5x its rest area (pressed), every marker present: one grown marker
    grown = np.r_[15.0, areas[1:]]
    t = pc.MarkerTracker(rest, rest_areas=areas, params=params)
    out = t.update(rest + 0.3, areas=grown)
    assert t.n_lost == 0 and np.allclose(out, rest + 0.3)
    plain = pc.MarkerTracker(rest, rest_areas=areas,
                             params=pc.TrackingParams(gate_fraction=1.0, use_velocity=False))
    plain.update(rest + 0.3, areas=grown)
    assert plain.status[0] == pc.MERGED  # the area-only rule flags it
    # a real merged pair: markers i and j (neighbours) seen as one big blob between them
    i = 0
    j = int(np.argsort(np.linalg.norm(rest - rest[i], axis=1))[1])
    det = np.vstack([np.delete(rest, [i, j], axis=0), 0.5 * (rest[i] + rest[j])])
    det_areas = np.r_[np.delete(areas, [i, j]), 12.0]
    t.reset()
    out = t.update(det, areas=det_areas)
    assert np.isnan(out[[i, j]]).all()
    assert sorted(t.status[[i, j]]) == [pc.LOST, pc.MERGED]
    # the same big blob with the missing marker far away (outside the gate): a grown marker
    k = int(np.argmax(np.linalg.norm(rest - rest[i], axis=1)))
    det = np.vstack([np.delete(rest, [i, k], axis=0), rest[i]])
    det_areas = np.r_[np.delete(areas, [i, k]), 12.0]
    t.reset()
    out = t.update(det, areas=det_areas)
    assert t.status[i] == pc.TRACKED and np.allclose(out[i], rest[i])
    assert t.status[k] == pc.LOST

