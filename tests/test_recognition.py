"""Tactile object recognition (tactip_lab.recognition): the object library, the contacts
through the chain, the bag of features with Bayesian fusion and information gain, the moment
BoW, the CNN and `tactip recognise`. Known answers where there are some; bad input refused."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from .conftest import ROOT

OBJECTS = ROOT / "scenes" / "objects"


# ----------------------------------------------------------------------------- the library
def test_library_has_the_objects_the_issue_asks_for():
    from tactip_lab.recognition.library import load_library

    lib = load_library(OBJECTS)
    assert len(lib.objects) >= 12
    names = set(lib.names)
    for n in ("cuboid", "cylinder", "triangular_prism", "small_sphere", "edge", "t_shape",
              "ring", "key", "small_cup_rim", "large_cup_rim", "textured_plate"):
        assert n in names
    stiff, soft = (lib.objects[lib.index(n)] for n in ("stiff_ball", "soft_ball"))
    assert stiff.params == soft.params and stiff.kind == soft.kind == "sphere"
    assert stiff.rigid and not soft.rigid
    for obj in lib.objects:  # every shape builds and answers the indenter protocol
        ind = obj.indenter()
        d, n = ind.sdf(np.array([[0.3, 0.2, -5.0]]))
        assert np.isfinite(d).all() and np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_library_refuses_bad_input(tmp_path):
    from tactip_lab.recognition.library import LibraryError, load_library

    lib = load_library(OBJECTS)
    with pytest.raises(ValueError, match="object='teapot' is not in the library"):
        lib.subset(["teapot"])
    with pytest.raises(LibraryError, match="no library.toml"):
        load_library(tmp_path)
    text = (OBJECTS / "library.toml").read_text()
    for f in [*OBJECTS.glob("*.wkt"), *OBJECTS.glob("*.stl")]:
        shutil.copy(f, tmp_path)
    (tmp_path / "library.toml").write_text(text.replace('kind = "torus"', 'kind = "donut"'))
    with pytest.raises(LibraryError, match="kind='donut' is not allowed"):
        load_library(tmp_path)
    stiff_box = text.replace('kind = "box"\n', 'kind = "box"\nyoungs_modulus_kpa = 9\n')
    (tmp_path / "library.toml").write_text(stiff_box)
    with pytest.raises(LibraryError, match="only modelled for kind='sphere'"):
        load_library(tmp_path)
    (tmp_path / "library.toml").write_text(text)
    (tmp_path / "key.wkt").unlink()
    with pytest.raises(LibraryError, match="outline='key.wkt': no such file"):
        load_library(tmp_path)


def test_prism_distance_and_lowest_point_match_its_mesh():
    """Two paths, one answer: the rounded prism's exact SDF (round 0) against trimesh's
    closest points and ray casts on the extruded mesh."""
    import trimesh

    from tactip_lab.recognition.object_indenters import Prism
    from tactip_lab.recognition.shapes import outline

    rng = np.random.default_rng(0)
    for name, axis, length in (("key.wkt", "z", 2.5), ("triangular_prism.wkt", "x", 16.0),
                               ("textured_plate.wkt", "y", 20.0)):
        p = Prism(outline(name), length, axis, round_mm=0.0)
        m = p.to_trimesh()
        assert m.is_watertight
        lo, hi = m.bounds
        q = rng.uniform(lo - 2, hi + 2, (400, 3))
        d, _ = p.sdf(q)
        _, dist, _ = trimesh.proximity.closest_point(m, q)
        ref = np.where(m.contains(q), -dist, dist)
        assert np.abs(d - ref).max() < 1e-6
        xy = rng.uniform(lo[:2], hi[:2], (200, 2))
        z = p.lower_z(xy)
        hits, rays, _ = m.ray.intersects_location(np.c_[xy, np.full(len(xy), lo[2] - 1)],
                                                  np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
        low = np.full(len(xy), np.nan)
        for h, r in zip(hits, rays, strict=True):
            low[r] = np.fmin(low[r], h[2])
        both = np.isfinite(low) & np.isfinite(z)
        assert both.sum() > 50 and np.abs(z[both] - low[both]).max() < 1e-6
    # rounding lowers a face-down prism by round_mm and widens its footprint by it
    from shapely.geometry import box

    r = Prism(box(-7.0, -4.5, 7.0, 4.5), 8.0, "z", round_mm=0.5)
    assert r.lower_z(np.array([[0.0, 0.0]]))[0] == pytest.approx(-0.5)
    assert np.isfinite(r.lower_z(np.array([[7.4, 0.0]])))[0]
    assert np.isnan(r.lower_z(np.array([[7.6, 0.0]])))[0]


def test_soft_ball_depth_split_known_answer():
    """With a Hertzian pad F = c d^1.5 the split is analytic: d_pad / d_ball = (c_b/c)^(2/3)."""
    from types import SimpleNamespace

    from tactip_lab.recognition.compliance import hertz_force_N, split_depth

    R, E, nu, depth = 20.0, 70.0, 0.5, 1.2
    c_ball = hertz_force_N(1.0, R, E, nu)
    assert c_ball == pytest.approx(4 / 3 * 0.07 / 0.75 * np.sqrt(R))
    c_pad = 0.53

    def press(d):
        return SimpleNamespace(force_N=c_pad * d**1.5)

    _, pad = split_depth(press, depth, R, E, nu)
    ratio = (c_ball / c_pad) ** (2 / 3)
    assert pad == pytest.approx(depth * ratio / (1 + ratio), abs=2e-4)
    with pytest.raises(ValueError, match="depth_mm"):
        split_depth(press, 0.0, R, E, nu)


# ------------------------------------------------------------------- fusion, information
def test_fusion_and_information_gain_known_answers():
    from tactip_lab.recognition.fusion import ActionModel, entropy, fuse

    post = fuse(np.array([[0.5, 0.25, 0.25], [0.5, 0.5, 0.125]]))
    assert np.allclose(post, np.array([0.25, 0.125, 0.03125]) / 0.40625)
    assert entropy(np.full(4, 0.25)) == pytest.approx(np.log(4))
    # action 0 observations look alike for every object (no gain); action 1's identify it
    lik = np.array([[1, 1], [1, 1], [1, 0.0], [0.0, 1]])
    model = ActionModel.build(lik, labels=np.array([0, 1, 0, 1]), actions=np.array([0, 0, 1, 1]),
                              n_classes=2, n_actions=2)
    gain = model.expected_gain(np.array([0.5, 0.5]))
    assert gain[0] == pytest.approx(0.0, abs=1e-12)
    assert gain[1] == pytest.approx(np.log(2))


def _synthetic(rng, n_per=20, noise=0.3):
    """4 objects, 3 actions: action 0 shows nothing, 1 splits the objects in pairs, 2 tells
    every object apart."""
    X, y, a = [], [], []
    for o in range(4):
        for act in range(3):
            m = np.zeros(6)
            if act == 1:
                m[0] = 3.0 * (o >= 2)
            elif act == 2:
                m[1 + o] = 3.0
            X.append(m + noise * rng.normal(size=(n_per, 6)))
            y += [o] * n_per
            a += [act] * n_per
    return np.concatenate(X), np.array(y), np.array(a)


def test_information_gain_never_worse_than_random_over_seeds():
    from tactip_lab.recognition.bof import BagOfFeatures
    from tactip_lab.recognition.fusion import ActionModel, run_trials

    acc = {"informed": [], "random": []}
    for seed in range(5):
        rng = np.random.default_rng(seed)
        (Xtr, ytr, atr), (Xte, yte, ate) = _synthetic(rng), _synthetic(rng)
        bof = BagOfFeatures(12, rng=seed).fit(Xtr, ytr, 4)
        model = ActionModel.build(bof.likelihood(Xtr), ytr, atr, 4, 3)
        objects = rng.choice(4, 200)
        for strat in acc:
            for repeat in (True, False):
                acc[strat].append(run_trials(
                    bof.likelihood(Xte), yte, ate, model, n_classes=4, trials=200,
                    contacts=3, strategy=strat, rng=seed, objects=objects,
                    repeat_actions=repeat).accuracy_by_contacts)
    informed, rand = np.mean(acc["informed"], axis=0), np.mean(acc["random"], axis=0)
    assert np.all(informed >= rand)
    assert informed[0] > rand[0] + 0.2  # it touches where the objects differ first
    assert informed[0] > 0.95


def test_bag_of_features_refuses_bad_input():
    from tactip_lab.recognition.bof import BagOfFeatures
    from tactip_lab.recognition.fusion import ActionModel, run_trials

    X = np.random.default_rng(0).normal(size=(10, 3))
    with pytest.raises(ValueError, match="k=11 is larger than the 10 training observations"):
        BagOfFeatures(11).fit(X, np.arange(10) % 2)
    with pytest.raises(ValueError, match="k=1 is out of range"):
        BagOfFeatures(1).fit(X, np.arange(10) % 2)
    with pytest.raises(ValueError, match="codebook="):
        BagOfFeatures(3, codebook="word")
    model = ActionModel.build(np.ones((2, 2)), np.array([0, 1]), np.array([0, 0]), 2, 1)
    with pytest.raises(ValueError, match="test set is empty"):
        run_trials(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int), model, n_classes=2,
                   trials=3, contacts=2, strategy="random", rng=0)
    with pytest.raises(ValueError, match="strategy='greedy'"):
        run_trials(np.ones((2, 2)), np.array([0, 1]), np.array([0, 0]), model, n_classes=2,
                   trials=3, contacts=2, strategy="greedy", rng=0)


# ------------------------------------------------------------------------ images, CNN
def test_moment_descriptors_known_answers():
    from tactip_lab.recognition.moments import moment_descriptors, patch_views

    p = np.zeros((1, 1, 5, 5))
    p[0, 0, 1, 3] = 2.0  # one bright pixel: centroid there, no spread
    d = moment_descriptors(p)[0, 0]
    assert d[0] == pytest.approx(np.log(3.0))
    assert d[1] == pytest.approx((3 - 2) / 5) and d[2] == pytest.approx((1 - 2) / 5)
    assert np.allclose(d[3:], 0.0)
    assert np.all(moment_descriptors(np.zeros((1, 2, 4, 4))) == 0.0)
    assert patch_views(np.zeros((3, 60, 80))).shape[:2] == (3, 30)  # the paper's 30 sub-images


def test_cnn_is_the_documented_network():
    """The forward pass (zero-padded 3x3 convolutions, ReLU, 2x2 max pooling, dense,
    softmax) against the same network computed with SciPy's 2-D correlation, same weights."""
    from scipy.signal import correlate2d

    from tactip_lab.recognition.cnn import SmallCNN

    rng = np.random.default_rng(0)
    net = SmallCNN(3, (8, 12), channels=(2, 3), rng=1)
    x = rng.normal(size=(4, 8, 12))
    conv1, conv2, dense = (m for m in net.net if hasattr(m, "weight"))
    w = [np.asarray(m.weight.detach(), dtype=float) for m in (conv1, conv2, dense)]
    b = [np.asarray(m.bias.detach(), dtype=float) for m in (conv1, conv2, dense)]

    def conv_relu_pool(a, wk, bk):
        z = np.stack([sum(correlate2d(a[i], wk[o, i], mode="same") for i in range(len(a)))
                      + bk[o] for o in range(len(wk))])
        z = np.maximum(z, 0.0)
        c, h, wd = z.shape
        return z.reshape(c, h // 2, 2, wd // 2, 2).max(axis=(2, 4))

    expect = []
    for img in x:
        a = conv_relu_pool(conv_relu_pool(img[None], w[0], b[0]), w[1], b[1])
        logits = w[2] @ a.ravel() + b[2]
        e = np.exp(logits - logits.max())
        expect.append(e / e.sum())
    p = net.predict_proba(x)
    assert p.shape == (4, 3) and np.allclose(p.sum(axis=1), 1.0)
    assert np.allclose(p, expect, rtol=1e-5, atol=1e-7)


def test_cnn_learns_where_the_blob_is_and_is_deterministic():
    from tactip_lab.recognition.cnn import SmallCNN

    rng = np.random.default_rng(0)
    y = rng.integers(0, 2, 64)
    x = 0.1 * rng.normal(size=(64, 12, 16))
    x[y == 0, 3:7, 2:6] += 1.0
    x[y == 1, 5:9, 10:14] += 1.0
    a = SmallCNN(2, (12, 16), rng=3).fit(x[:48], y[:48], epochs=6)
    b = SmallCNN(2, (12, 16), rng=3).fit(x[:48], y[:48], epochs=6)
    assert np.array_equal(a.predict_proba(x[48:]), b.predict_proba(x[48:]))
    assert np.mean(a.predict_proba(x[48:]).argmax(axis=1) == y[48:]) == 1.0
    c = SmallCNN(2, (12, 16), rng=4).fit(x[:48], y[:48], epochs=6)
    assert not np.array_equal(a.predict_proba(x[48:]), c.predict_proba(x[48:]))
    with pytest.raises(ValueError, match="multiples of 4"):
        SmallCNN(2, (10, 16))
    with pytest.raises(ValueError, match="labels y span 0..2"):
        SmallCNN(2, (12, 16)).fit(x[:3], np.array([0, 1, 2]))


# ---------------------------------------------------------------- through the chain, CLI
@pytest.fixture(scope="module")
def two_objects(tmp_path_factory):
    """Contacts with two very different objects (a flat plate and a straight edge), through the
    shared chain at 320x240, 1 frame, 4 repeats of the 7 positions."""
    import tactip_sim as ts
    from tactip_lab.recognition.contacts import ContactSpec, generate
    from tactip_lab.recognition.library import load_library
    from tactip_lab.recognition.recognition_cli import QUICK_CAMERA

    scene = ts.replace_in(ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml"),
                          camera=QUICK_CAMERA)
    lib = load_library(OBJECTS).subset(["edge", "flat_plate"])
    spec = ContactSpec(scene, lib, repeats=4)
    out = tmp_path_factory.mktemp("contacts") / "contacts"
    first, info1 = generate(spec, out, progress=False, limit=5)  # interrupted ...
    assert first is None and info1["computed"] == 5
    cs, info2 = generate(spec, out, progress=False)  # ... and resumed
    assert info2 == {**info2, "computed": spec.n_contacts - 5, "skipped": 5}
    # the folder keeps the mesh its contacts were computed with (a resume elsewhere uses it)
    from tactip_lab.recognition.store import ContactDataset
    from tactip_lab.sampling.dataset import stored_mesh

    kept = stored_mesh(out, spec.scene)
    assert kept.digest == ContactDataset(out).manifest()["identity"]["mesh_digest"]
    return spec, cs, out


def test_two_very_different_objects_are_told_apart_with_one_contact(two_objects):
    from tactip_lab.recognition.studies import Settings, bof_fold, split_folds

    _, cs, _ = two_objects
    assert len(cs) == 2 * 7 * 4 and cs.disp_px.shape[1:] == (97, 2)
    s = Settings(k=8, runs=2, trials=100, contacts=3)
    for i, train in enumerate(split_folds(cs, 2, 0)):
        r = bof_fold(cs, train, s, k=8, factor=0.5, seed=i)
        assert r["random"]["accuracy_by_contacts"][0] == 1.0
        assert r["informed"]["accuracy_by_contacts"][0] == 1.0


def test_contacts_are_deterministic_and_resume_bit_for_bit(two_objects, tmp_path):
    from tactip_lab.recognition.contacts import chain_for, contact

    spec, cs, out = two_objects
    chain, sim = chain_for(spec.with_mesh())
    again = contact(chain, sim, spec, 3)  # one of the contacts made before the interruption
    assert np.array_equal(again["disp_px"], cs.disp_px[3], equal_nan=True)
    assert np.array_equal(again["image"], cs.images[3])
    assert cs.pad_depth_mm[3] == again["pad_depth_mm"]


def test_contact_dataset_refuses_other_contacts_and_empty_folders(two_objects, tmp_path):
    from dataclasses import replace

    from tactip_lab.recognition.contacts import generate, load_contacts
    from tactip_lab.sampling.dataset import DatasetError

    spec, _, out = two_objects
    with pytest.raises(DatasetError, match="already holds other contacts"):
        generate(replace(spec, repeats=3), out, progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="not a contacts data set"):
        load_contacts(tmp_path / "empty")
    with pytest.raises(ValueError, match="objects=\\['teapot'\\] not in the data set"):
        load_contacts(out).objects(["teapot", "flat_plate"])


def test_soft_ball_takes_part_of_the_commanded_depth(two_objects):
    from tactip_lab.recognition.contacts import chain_for, draw_pose, press_object
    from tactip_lab.recognition.library import load_library

    spec, _, _ = two_objects
    _, sim = chain_for(spec.with_mesh())
    lib = load_library(OBJECTS)
    pose = draw_pose(lib, lib.objects[lib.index("soft_ball")], 3, 0, 0, seed=0)
    soft, pad_soft = press_object(sim, lib.objects[lib.index("soft_ball")], pose)
    stiff, pad_stiff = press_object(sim, lib.objects[lib.index("stiff_ball")], pose)
    assert pad_stiff == pose.depth_mm and 0.2 * pose.depth_mm < pad_soft < 0.8 * pose.depth_mm
    from tactip_lab.recognition.compliance import hertz_force_N

    ball = hertz_force_N(pose.depth_mm - pad_soft, 20.0, 70.0, 0.5)
    assert soft.force_N == pytest.approx(ball, rel=1e-3)  # forces match across the spring
    assert soft.force_N < stiff.force_N


def _run(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "tactip_sim.commands", *args], cwd=cwd,
                          capture_output=True, text=True)


@pytest.fixture(scope="module")
def recognised(two_objects, tmp_path_factory):
    """`tactip recognise` on the two objects' contacts (reused: copied into its folder)."""
    _, _, contacts = two_objects
    out = tmp_path_factory.mktemp("recognise")
    shutil.copytree(contacts, out / "contacts")
    args = ["recognise", str(ROOT / "scenes" / "shadow_fingertip.toml"), "--objects",
            str(OBJECTS), "--object", "edge,flat_plate", "--out", str(out), "--quick",
            "--repeats", "4", "--k", "8", "--ks", "4,8", "--trials", "60", "--contacts", "4",
            "--cnn-epochs", "2", "--no-progress"]
    res = _run(*args)
    assert res.returncode == 0, res.stderr
    return out, args


def test_recognise_writes_the_summary_and_resumes(recognised):
    out, args = recognised
    s = json.loads((out / "summary.json").read_text())
    assert set(s["accuracy_by_contacts"]) >= {"informed", "random"}
    assert len(s["accuracy_by_contacts"]["informed"]) == 4
    assert s["accuracy_one_contact"] == 1.0
    assert s["contacts"]["skipped"] == 56 and s["contacts"]["computed"] == 0
    assert set(s["methods"]) == {"bof", "svm_markers", "moments_svm", "cnn"}
    for f in ("manifest.json", "report.md", "charts/accuracy_vs_contacts.png",
              "charts/speed_vs_accuracy.png", "charts/accuracy_vs_k.png", "charts/confusion.png",
              "tables/accuracy_by_contacts.csv", "tables/methods.csv"):
        assert (out / f).is_file(), f
    res = _run(*args)  # a rerun recomputes nothing
    assert res.returncode == 0, res.stderr
    again = json.loads((out / "summary.json").read_text())
    assert again["steps"]["computed"] == [] and again["accuracy_by_contacts"] == \
        s["accuracy_by_contacts"]


def test_recognise_refuses_bad_input(recognised, tmp_path):
    # the command in this process (``tactip_sim.commands.main``, as tests/test_outputs.py
    # runs them): a refusal is its exit code and message, not the interpreter's start, which
    # the run above and tests/test_cli.py check
    from .test_outputs import tactip

    out, args = recognised
    rc, err = tactip(*[a if a != "edge,flat_plate" else "edge,teapot" for a in args])
    assert rc != 0 and "object='teapot' is not in the library" in err
    rc, err = tactip(*[a if i != args.index("--k") + 1 else "500" for i, a in enumerate(args)])
    assert rc != 0 and "k=500 is larger than the" in err
    (tmp_path / "lib").mkdir()  # (beside --out: an output inside an input is refused)
    rc, err = tactip("recognise", str(ROOT / "scenes" / "shadow_fingertip.toml"), "--objects",
                     str(tmp_path / "lib"), "--out", str(tmp_path / "o"))
    assert rc != 0 and "no library.toml" in err


@pytest.mark.slow
def test_quick_study_of_the_whole_library(tmp_path):
    """`tactip recognise --quick` on all 15 objects, then `tactip select-markers --quick` on
    its contacts: well above chance (1/15) after 10 contacts, every output written."""
    out = tmp_path / "rec"
    res = _run("recognise", str(ROOT / "scenes" / "shadow_fingertip.toml"), "--objects",
               str(OBJECTS), "--out", str(out), "--quick", "--no-progress")
    assert res.returncode == 0, res.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["contacts"]["n"] == 15 * 7 * 4
    assert s["accuracy_T_random"] > 4 * s["chance"]
    assert s["subsets"]["balls"]["accuracy_T"] > 0.6
    sel = tmp_path / "sel"
    res = _run("select-markers", str(out), "--out", str(sel), "--quick", "--no-progress")
    assert res.returncode == 0, res.stderr
    m = json.loads((sel / "summary.json").read_text())
    assert m["cv_accuracy"]["object"]["all"] > 4 * s["chance"]


def test_a_torn_contacts_file_is_named_and_rebuilt_from_the_records(two_objects, tmp_path):
    import shutil

    from tactip_lab.recognition.store import ContactDataset
    from tactip_lab.sampling.dataset import DatasetError
    from tactip_lab.sampling.manifest import readable_zip

    spec, cs, out = two_objects
    copy = tmp_path / "contacts"
    shutil.copytree(out, copy)
    stacked = copy / "contacts.npz"
    stacked.write_bytes(stacked.read_bytes()[:500])  # was a BadZipFile traceback
    ds = ContactDataset(copy)
    with pytest.raises(DatasetError, match="contacts.npz is unreadable"):
        ds.load()
    assert not readable_zip(stacked)  # what generate() checks to rebuild it on a rerun
    ds.finalise(spec.n_contacts)
    assert np.array_equal(ds.load().disp_px, cs.disp_px, equal_nan=True)
