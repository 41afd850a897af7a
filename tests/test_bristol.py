"""Labelled folders in the Bristol layout: `tactip fit / evaluate / features` on folders built
here from synthetic frames with known contact points, cross-validation against scikit-learn, and
the errors a malformed folder gets."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

import perception as pc
from perception.synthetic import render_markers
from tactip_lab.fitting.bristol import BristolFolder, ColumnMap, cross_validate, folder_features
from tactip_lab.fitting.fit import FeatureTable
from tactip_lab.sampling.dataset import DatasetError

C = np.array([320.0, 240.0])
SPACING = 26.0
ROLL_PER_PX, PITCH_PER_PX = 0.12, -0.08  # the labels: angles linear in the contact point


def _frame(contact: np.ndarray | None, rng: np.random.Generator) -> np.ndarray:
    """Markers pushed away from ``contact`` (a Gaussian bulge 2 spacings wide): the cells
    around the contact grow, so the growth-weighted CoP follows the contact point."""
    pts = pc.hex_lattice(97, SPACING, C)
    if contact is not None:
        d = pts - contact
        r = np.linalg.norm(d, axis=1, keepdims=True)
        push = 9.0 * np.exp(-((r / (2.0 * SPACING)) ** 2)) * d / np.maximum(r, 1e-9)
        pts = pts + push
    return render_markers(pts, diameter_px=11.0, noise_sigma=0.01, rng=rng).image


def _write_folder(root, contacts, *, image_col="sensor_image", subdir=True, rest_first=True):
    """targets.csv in the Bristol columns; frame 0 is the rest frame (depth 0), the others
    are presses at depth 1-3 mm whose angles are linear in the contact point."""
    rng = np.random.default_rng(7)
    img_dir = root / "images" if subdir else root
    img_dir.mkdir(parents=True, exist_ok=True)
    rows = [f"{image_col},pose_1,pose_2,pose_3,pose_4,pose_5,pose_6"]
    frames = ([None] if rest_first else []) + list(contacts)
    for i, c in enumerate(frames):
        name = f"image_{i + 1}.png"
        cv2.imwrite(str(img_dir / name), _frame(c, rng))
        if c is None:
            roll = pitch = depth = 0.0
        else:
            roll, pitch = ROLL_PER_PX * (c[0] - C[0]), PITCH_PER_PX * (c[1] - C[1])
            depth = 1.0 + 2.0 * rng.random()
        rows.append(f"{name},0,0,{depth},{roll},{pitch},0")
    (root / "targets.csv").write_text("\n".join(rows) + "\n")
    return root


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    rng = np.random.default_rng(3)
    contacts = C + rng.uniform(-70, 70, (24, 2))
    return _write_folder(tmp_path_factory.mktemp("bristol") / "taps", contacts), contacts


def test_folder_reads_columns_images_and_picks_the_frame_without_contact_as_rest(folder):
    root, contacts = folder
    f = BristolFolder.open(root)
    assert len(f) == len(contacts) + 1 and f.image_size == (640, 480)
    assert f.rest.name == "image_1.png" and "without contact" in f.rest_choice  # depth 0
    assert not f.reference_is_a_press
    np.testing.assert_allclose(f.angles_deg[1:, 0], ROLL_PER_PX * (contacts[:, 0] - C[0]))
    flipped = BristolFolder.open(root, columns=ColumnMap(roll_sign=-1.0))
    np.testing.assert_array_equal(flipped.angles_deg[:, 0], -f.angles_deg[:, 0])


def test_median_of_binarised_frames_keeps_the_majority_level():
    """Five binarised frames of one bar shifted by -2 ... +2 px: each pixel takes the level
    at least half of the frames give it, so the median is the middle frame's bar."""
    from tactip_lab.fitting.bristol import median_reference

    frames = []
    for dx in (-2, -1, 0, 1, 2):
        f = np.zeros((40, 60), np.uint8)
        f[14:27, 24 + dx:37 + dx] = 255
        frames.append(f)
    paths = []
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        for i, f in enumerate(frames):
            paths.append(Path(tmp) / f"f{i}.png")
            cv2.imwrite(str(paths[i]), f)
        med = median_reference(paths)
    assert med.dtype == np.uint8 and set(np.unique(med)) == {0, 255}
    np.testing.assert_array_equal(med, frames[2])


def test_without_a_rest_frame_the_median_of_the_shallowest_taps_is_nearer_rest(tmp_path):
    """Taps at random contact points and no frame without contact: the median of the
    shallowest taps puts the markers nearer their rest lattice than any of those taps does
    (each tap pushes the markers around its contact point). Deeper taps stay out of it."""
    rng = np.random.default_rng(11)
    (tmp_path / "images").mkdir()
    rows = ["sensor_image,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6"]
    n = 40
    for i in range(n):
        contact = C + rng.uniform(-70, 70, 2)
        cv2.imwrite(str(tmp_path / "images" / f"t{i}.png"), _frame(contact, rng))
        depth = 1.0 + 0.001 * i if i < 10 else 2.0 + rng.random()  # 10 shallow, 30 deeper
        rows.append(f"t{i}.png,0,0,{depth},{rng.normal()},{rng.normal()},0")
    (tmp_path / "targets.csv").write_text("\n".join(rows) + "\n")
    f = BristolFolder.open(tmp_path)
    assert f.rest.name == "t0.png" and "median of the 6 shallowest" in f.rest_choice
    assert f.reference_is_a_press and f.with_single_rest("a test").reference_is_a_press
    lattice = pc.hex_lattice(97, SPACING, C)

    def error(ref):
        det = pc.detect_markers_detailed(ref, expected_count=97)
        d, _ = cKDTree(det.points).query(lattice)
        return float(np.mean(d))

    singles = [error(str(tmp_path / "images" / f"t{i}.png")) for i in range(6)]
    assert error(f.reference) < min(singles)  # nearer rest than any tap it was made from
    frames = folder_features(f, perceive=True)
    assert frames.summary()["rest_choice"] == f.rest_choice and frames.reliable.all()


def test_a_plain_labels_csv_with_descriptive_columns_is_read(folder, tmp_path):
    """A folder with ``labels.csv`` (image, depth_mm, roll_deg_Rx, pitch_deg_Ry) in place of
    targets.csv: the same frames, angles and rest choice as the Bristol columns give; a column
    named on the command line is kept even where an alias exists."""
    import shutil

    root, _ = folder
    plain = tmp_path / "plain"
    shutil.copytree(root / "images", plain)
    rows = (root / "targets.csv").read_text().splitlines()
    out = ["image,depth_mm,roll_deg_Rx,pitch_deg_Ry,pose_4"]
    for line in rows[1:]:
        name, _, _, depth, roll, pitch, _ = line.split(",")
        out.append(f"{name},{depth},{roll},{pitch},42")  # a decoy pose_4 column
    (plain / "labels.csv").write_text("\n".join(out) + "\n")
    ref = BristolFolder.open(root)
    f = BristolFolder.open(plain)
    assert (f.columns.roll, f.columns.pitch, f.columns.depth) == ("pose_4", "pitch_deg_Ry",
                                                                  "depth_mm")
    assert np.all(f.angles_deg[:, 0] == 42)  # pose_4 is present: the default stays
    f = BristolFolder.open(plain, columns=ColumnMap(roll="roll_deg_Rx"))
    np.testing.assert_array_equal(f.angles_deg, ref.angles_deg)
    assert f.rest.name == ref.rest.name and [p.name for p in f.images] == \
        [p.name for p in ref.images]
    (plain / "labels.csv").write_text("\n".join(o.rsplit(",", 1)[0] for o in out) + "\n")
    f = BristolFolder.open(plain)  # no pose_4 now: roll_deg_Rx is taken
    assert f.columns.roll == "roll_deg_Rx"
    np.testing.assert_array_equal(f.angles_deg, ref.angles_deg)


def test_growth_cop_follows_the_known_contact_points(folder):
    root, contacts = folder
    frames = folder_features(BristolFolder.open(root))
    assert frames.reliable.all(), frames.reason
    cop = frames.cop["growth"][1:]
    # the growth-weighted CoP lies near the contact point (the bulge is symmetric about it,
    # clipped only by the lattice's edge)
    err = np.linalg.norm(cop - contacts, axis=1)
    assert np.median(err) < 0.3 * SPACING, err


def test_fit_cv_and_evaluate_commands_write_the_contract_json(folder, tmp_path, capsys):
    from tactip_sim.commands import main

    root, _ = folder
    model, cv_json, ev_json = tmp_path / "m.json", tmp_path / "cv.json", tmp_path / "ev.json"
    assert main(["fit", str(root), "--order", "1", "--out", str(model), "--cv", "5",
                 "--json", str(cv_json), "--no-progress"]) == 0
    cv = json.loads(cv_json.read_text())
    # the rest frame has no growth, so no growth CoP: 24 of the 25 rows are used
    assert cv["n_used"] == 24 and cv["n_flagged"] == 0 and cv["n_rows"] == 25
    assert cv["r2_roll"] > 0.9 and cv["r2_pitch"] > 0.9  # angles are linear in the contact
    saved = json.loads(model.read_text())
    assert saved["fitted_on"]["feature"] == "growth"
    assert saved["fitted_on"]["image_size"] == [640, 480]
    assert main(["evaluate", str(model), str(root), "--json", str(ev_json),
                 "--no-progress"]) == 0
    ev = json.loads(ev_json.read_text())
    assert {"r2_roll", "r2_pitch", "n_used", "n_flagged"} <= set(ev)
    assert ev["r2_roll"] >= cv["r2_roll"]  # scored on its own training data
    out = tmp_path / "features.csv"
    assert main(["features", str(root), "--out", str(out), "--no-progress"]) == 0
    lines = out.read_text().splitlines()
    assert len(lines) == 26 and lines[0].startswith("index,image,roll_deg")
    capsys.readouterr()
    assert main(["evaluate", str(model), str(root), "--feature", "area", "--no-progress"]) != 0
    assert "fitted on the 'growth' CoP" in capsys.readouterr().err


def test_cross_validation_matches_scikit_learn():
    from sklearn.linear_model import LinearRegression
    from sklearn.metrics import r2_score
    from sklearn.model_selection import PredefinedSplit, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import PolynomialFeatures

    rng = np.random.default_rng(11)
    cop = rng.uniform(100, 500, (60, 2))
    u = (cop - 300) / 200
    angles = np.stack([10 * u[:, 0] + 3 * u[:, 0] * u[:, 1], -6 * u[:, 1] + 2 * u[:, 1] ** 2],
                      axis=1) + rng.normal(0, 0.5, (60, 2))
    table = FeatureTable(cop, angles, np.zeros(60), np.zeros(0, int), (640, 480))
    ours = cross_validate(table, 2, 5, seed=4)
    fold = np.empty(60, int)  # the same folds: every 5th sample of a seeded permutation
    perm = np.random.default_rng(4).permutation(60)
    for k in range(5):
        fold[perm[k::5]] = k
    ref = cross_val_predict(make_pipeline(PolynomialFeatures(2, include_bias=False),
                                          LinearRegression()), cop, angles,
                            cv=PredefinedSplit(fold))
    np.testing.assert_allclose(ours["predicted_deg"], ref, atol=1e-8)
    assert ours["r2_roll"] == pytest.approx(r2_score(angles[:, 0], ref[:, 0]), abs=1e-10)
    assert ours["r2_pitch"] == pytest.approx(r2_score(angles[:, 1], ref[:, 1]), abs=1e-10)
    with pytest.raises(ValueError, match="--cv=1 is out of range"):
        cross_validate(table, 2, 1)


def test_malformed_folders_get_errors_naming_the_file(tmp_path, folder):
    root, contacts = folder
    with pytest.raises(DatasetError, match="no targets.csv"):
        BristolFolder.open(tmp_path)
    bad = _write_folder(tmp_path / "missing", contacts[:3])
    (bad / "images" / "image_2.png").unlink()
    with pytest.raises(DatasetError, match="row 2 names 'image_2.png'"):
        BristolFolder.open(bad)
    with pytest.raises(DatasetError, match="no column 'Rx'"):
        BristolFolder.open(root, columns=ColumnMap(roll="Rx"))
    with pytest.raises(DatasetError, match="no image column"):
        BristolFolder.open(root, columns=ColumnMap(image="frame"))
    mixed = _write_folder(tmp_path / "mixed", contacts[:3], subdir=False)
    cv2.imwrite(str(mixed / "image_3.png"), np.zeros((128, 128), np.uint8))
    with pytest.raises(DatasetError, match="images of different sizes"):
        BristolFolder.open(mixed)
    small_rest = tmp_path / "rest128.png"
    cv2.imwrite(str(small_rest), np.zeros((128, 128), np.uint8))
    with pytest.raises(DatasetError, match="rest frame of another sensor"):
        BristolFolder.open(root, rest=small_rest)
    other = tmp_path / "other_sensor.png"  # same size, a 37-marker sensor
    cv2.imwrite(str(other), render_markers(pc.hex_lattice(37, SPACING, C), diameter_px=11.0,
                                           noise_sigma=0.01, rng=np.random.default_rng(0)).image)
    with pytest.raises(DatasetError, match=r"other_sensor.png: the reference frame shows 37 "
                       r"markers but the folder.s first frames a median of 97"):
        folder_features(BristolFolder.open(root, rest=other))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.zeros((480, 640), np.uint8))
    with pytest.raises(DatasetError, match="reference frame cannot be used"):
        folder_features(BristolFolder.open(root, rest=blank))


def test_a_model_of_another_image_format_is_refused(folder, tmp_path, capsys):
    from tactip_sim.commands import main

    root, _ = folder
    model = tmp_path / "m.json"
    assert main(["fit", str(root), "--order", "1", "--out", str(model), "--no-progress"]) == 0
    data = json.loads(model.read_text())
    data["image_size"] = [128, 128]  # as if fitted on the lab's processed frames
    model.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["evaluate", str(model), str(root), "--no-progress"]) != 0
    assert "fitted on 128x128 frames" in capsys.readouterr().err
    assert main(["evaluate", str(model), str(root), "--rescale", "--no-progress"]) == 0


def test_fit_never_overwrites_a_file_that_is_not_a_model(folder, tmp_path, capsys):
    from tactip_sim.commands import main

    root, _ = folder
    thesis = tmp_path / "thesis.txt"
    thesis.write_text("three years of work")
    assert main(["fit", str(root), "--order", "1", "--out", str(thesis), "--no-progress"]) != 0
    assert "is not a model file" in capsys.readouterr().err
    assert thesis.read_text() == "three years of work"
    model = tmp_path / "m.json"
    for _ in range(2):  # a model may replace a model
        assert main(["fit", str(root), "--order", "1", "--out", str(model),
                     "--no-progress"]) == 0


def test_the_flow_feature_fits_evaluates_and_replaces_its_own_model(folder, tmp_path, capsys):
    from tactip_sim.commands import main

    root, _ = folder
    model, cv_json, ev_json = tmp_path / "m.json", tmp_path / "cv.json", tmp_path / "ev.json"
    chart = tmp_path / "chart.png"
    for _ in range(2):  # the second fit replaces the first model file
        assert main(["fit", str(root), "--feature", "flow", "--order", "1", "--out", str(model),
                     "--cv", "5", "--json", str(cv_json), "--plot", str(chart),
                     "--no-progress"]) == 0
    assert chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main(["fit", str(root), "--order", "1", "--out", str(model), "--plot", str(chart),
                 "--no-progress"]) != 0
    assert "give --cv K too" in capsys.readouterr().err
    saved = json.loads(model.read_text())
    assert saved["format"] == "perception.VectorRegressor"
    assert saved["fitted_on"]["feature"] == "flow"
    cv = json.loads(cv_json.read_text())
    # the rest frame has no motion (no weighted centroid): 24 of the 25 rows; the bulge pushes
    # the markers away from the contact, so the array's motion carries the contact point
    assert cv["n_used"] == 24 and cv["r2_roll"] > 0.8 and cv["r2_pitch"] > 0.8
    assert main(["evaluate", str(model), str(root), "--json", str(ev_json),
                 "--no-progress"]) == 0
    ev = json.loads(ev_json.read_text())
    assert ev["feature"] == "flow" and ev["n_used"] == 24
    assert ev["r2_roll"] >= cv["r2_roll"] and ev["r2_pitch"] >= cv["r2_pitch"]
    data = json.loads(model.read_text())
    data["image_size"] = [128, 128]
    model.write_text(json.dumps(data))
    assert main(["evaluate", str(model), str(root), "--rescale", "--no-progress"]) != 0
    assert "cannot be rescaled" in capsys.readouterr().err
