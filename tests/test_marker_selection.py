"""Marker selection (tactip_lab.recognition.id3 / select): ID3 information gain, LogitBoost
stumps, the Table II evaluation and `tactip select-markers`. Known answers on synthetic
marker fields; the command end to end on contacts made through the chain."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from .conftest import ROOT


def test_information_gain_known_answers():
    from tactip_lab.recognition.id3 import information_gain

    y = np.array([0, 0, 1, 1])
    codes = np.array([[0, 0, 5], [0, 1, 5], [1, 0, 5], [1, 1, 5]])  # copy, independent, const
    gain = information_gain(codes, y)
    assert gain == pytest.approx([1.0, 0.0, 0.0])
    three = information_gain(np.array([[0], [1], [2]] * 4), np.array([0, 1, 2] * 4))
    assert three[0] == pytest.approx(np.log2(3))


def _field(rng, n, q=20, informative=7, channel=2):
    """Noise everywhere; one input of one marker carries a two-class label."""
    y = rng.integers(0, 2, n)
    field = rng.normal(0, 1, (n, q, 3))
    field[:, informative, channel] = np.where(y == 1, 1.0, -1.0) + 0.01 * rng.normal(size=n)
    return field, y


def test_id3_picks_the_one_informative_marker():
    from tactip_lab.recognition.id3 import ID3, discretise
    from tactip_lab.recognition.select import select_markers

    rng = np.random.default_rng(0)
    for seed, marker, channel in ((0, 7, 2), (1, 13, 0), (2, 0, 1)):
        field, y = _field(np.random.default_rng(seed), 200, informative=marker,
                          channel=channel)
        X = field.reshape(len(y), -1)
        for bins in (2, 3, 5):
            assert select_markers(X, y, 20, bins=bins, min_samples_split=2) == [marker]
        codes, edges = discretise(X, 3)
        tree = ID3().fit(codes, y)
        assert tree.features_ == [3 * marker + channel] and tree.n_nodes_ == 1
        test, yt = _field(rng, 50, informative=marker, channel=channel)
        assert np.all(tree.predict(discretise(test.reshape(50, -1), edges=edges)[0]) == yt)


def test_id3_and_discretise_refuse_bad_input():
    from tactip_lab.recognition.id3 import ID3, cv_accuracy, discretise

    with pytest.raises(ValueError, match="one class"):
        ID3().fit(np.zeros((5, 2), int), np.zeros(5, int))
    with pytest.raises(ValueError, match="empty"):
        ID3().fit(np.zeros((0, 2), int), np.zeros(0, int))
    with pytest.raises(ValueError, match="bins=1"):
        discretise(np.zeros((4, 2)), 1)
    with pytest.raises(ValueError, match="booster='svm'"):
        cv_accuracy(np.zeros((8, 1)), np.arange(8) % 2, kind="svm")
    with pytest.raises(ValueError, match="4-fold cross-validation needs at least 4"):
        cv_accuracy(np.zeros((6, 1)), np.array([0, 0, 0, 1, 1, 1]))


def test_boosted_stumps_learn_a_threshold():
    from tactip_lab.recognition.boost import LogitBoost
    from tactip_lab.recognition.id3 import cv_accuracy

    rng = np.random.default_rng(0)
    X = rng.normal(size=(160, 6))
    y = np.digitize(X[:, 4], [-0.4, 0.4])  # three classes from one input
    assert cv_accuracy(X, y, kind="logitboost") > 0.95
    assert cv_accuracy(X, (X[:, 2] > 0).astype(int), kind="adaboost") > 0.95
    lb = LogitBoost(10).fit(X, y)
    assert {int(f) for stump in lb.stumps_ for f in stump[0]} == {4}  # only the input that
    assert lb.decision_function(X).shape == (160, 3)                  # matters is used


def _contact_set(rng, n=120, pins=37):
    """A synthetic contact set of a 37-pin pad: pin 12's dx tells the object, pin 30's dy the
    roll, pin 5's growth the pitch; every other input is noise."""
    import perception as pc
    from tactip_lab.recognition.contacts import ContactSet

    rest = pc.hex_lattice(pins, 20.0, (320.0, 240.0))
    labels = rng.integers(0, 2, n)
    roll, pitch = rng.uniform(-3, 3, n), rng.uniform(-3, 3, n)
    disp = rng.normal(0, 0.5, (n, pins, 2))
    growth = rng.normal(0, 0.05, (n, pins))
    disp[:, 12, 0] = 3.0 * labels
    disp[:, 30, 1] = roll
    growth[:, 5] = 0.1 * pitch
    actions = rng.integers(0, 3, n)
    poses = np.stack([roll, pitch, rng.uniform(-5, 5, n), rng.uniform(0.8, 1.4, n),
                      np.zeros(n), np.zeros(n)], axis=1)
    return ContactSet(
        disp_px=disp, growth=growth, images=np.zeros((n, 8, 8), np.uint8),
        rest_image=np.zeros((8, 8), np.uint8), labels=labels, actions=actions,
        repeats=np.zeros(n, int), poses=poses, pad_depth_mm=poses[:, 3], force_N=np.ones(n),
        names=("a", "b"), groups=("g", "g"), actions_mm=(-3.0, 0.0, 3.0), rest_pins_px=rest,
        rest_full=np.zeros((480, 640), np.uint8), meta={"identity": {"synthetic": True}})


def test_selection_finds_each_tasks_marker_and_fills_table_ii(tmp_path):
    from tactip_lab.recognition.select import ROWS, run_selection

    cs = _contact_set(np.random.default_rng(1))
    s = run_selection(cs, tmp_path, min_samples_split=20, progress=False)
    sel = s["selected_marker_ids"]
    assert sel["object"] == [12]
    assert sel["roll"][0] == 30 and sel["pitch"][0] == 5
    for task in ("object", "roll", "pitch"):
        acc = s["cv_accuracy"][task]
        assert set(acc) == {"all", "selected", "non_selected"}
        assert acc["selected"] >= 0.85 and acc["all"] >= 0.85
        assert acc["non_selected"] < acc["selected"] - 0.2  # the rest hold no information
        assert set(s["tasks"][task]["accuracy"]) == set(ROWS)
        assert s["tasks"][task]["accuracy"]["an"] < 0.7  # proprioception: no label in it
    for f in ("summary.json", "manifest.json", "report.md", "tables/table_ii.csv",
              "tables/selected_markers.csv", "charts/selected_markers.png"):
        assert (tmp_path / f).is_file(), f
    table = (tmp_path / "tables" / "table_ii.csv").read_text().splitlines()
    assert table[0] == "row,object (%),roll (%),pitch (%)" and len(table) == 8
    again = run_selection(cs, tmp_path, min_samples_split=20, progress=False)
    assert again["steps"]["computed"] == [] and again["cv_accuracy"] == s["cv_accuracy"]


def test_selection_refuses_one_class_and_empty_data(tmp_path):
    from tactip_lab.recognition.select import run_selection, task_labels

    cs = _contact_set(np.random.default_rng(2), n=40)
    one = cs.subset(cs.labels == 0)
    with pytest.raises(ValueError, match="task='object': the labels have one class"):
        run_selection(one, tmp_path, tasks=("object",), progress=False)
    flat = cs.subset(np.arange(len(cs)))
    flat.poses[:, 0] = 1.0
    with pytest.raises(ValueError, match="task='roll': the labels have one class"):
        task_labels(flat, "roll")
    with pytest.raises(ValueError, match="empty"):
        task_labels(cs.subset(np.zeros(len(cs), bool)), "object")
    with pytest.raises(ValueError, match="task='grasp' is not allowed"):
        task_labels(cs, "grasp")


@pytest.fixture(scope="module")
def contacts_folder(tmp_path_factory):
    """Contacts with three objects through the chain (320x240, 1 frame, 3 repeats)."""
    import tactip_sim as ts
    from tactip_lab.recognition.contacts import ContactSpec, generate
    from tactip_lab.recognition.library import load_library
    from tactip_lab.recognition.recognition_cli import QUICK_CAMERA

    scene = ts.replace_in(ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml"),
                          camera=QUICK_CAMERA)
    lib = load_library(ROOT / "scenes" / "objects").subset(["edge", "flat_plate",
                                                             "stiff_ball"])
    out = tmp_path_factory.mktemp("sel") / "contacts"
    generate(ContactSpec(scene, lib, repeats=3), out, progress=False)
    return out


def _run(*args):
    return subprocess.run([sys.executable, "-m", "tactip_sim.commands", *args], cwd=ROOT,
                          capture_output=True, text=True)


def test_select_markers_command(contacts_folder, tmp_path):
    out = tmp_path / "sel"
    # two of the three tasks: the option reaches the selection, and a third of the boosting
    # is saved (test_selection_finds_each_tasks_marker_and_fills_table_ii runs all three)
    res = _run("select-markers", str(contacts_folder), "--out", str(out), "--quick",
               "--tasks", "object,pitch", "--no-progress")
    assert res.returncode == 0, res.stderr
    s = json.loads((out / "summary.json").read_text())
    assert set(s["selected_marker_ids"]) == {"object", "pitch"}
    for task, ids in s["selected_marker_ids"].items():
        assert 1 <= len(ids) <= 97 and all(0 <= i < 97 for i in ids)
        acc = s["cv_accuracy"][task]
        assert all(0.0 <= acc[k] <= 1.0 for k in ("all", "selected", "non_selected"))
    assert s["cv_accuracy"]["object"]["all"] > 0.8  # three very different objects
    assert (out / "manifest.json").is_file() and (out / "charts" / "selected_markers.png").is_file()
    assert "(7) NKey-Co." in (out / "report.md").read_text()


def test_select_markers_command_refuses_bad_input(contacts_folder, tmp_path):
    # the command in this process (``tactip_sim.commands.main``, as tests/test_outputs.py
    # runs them): a refusal is its exit code and message, not the interpreter's start, which
    # test_select_markers_command and tests/test_cli.py check
    from .test_outputs import tactip

    rc, err = tactip("select-markers", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"))
    assert rc != 0 and "no such folder" in err
    (tmp_path / "empty").mkdir()
    rc, err = tactip("select-markers", str(tmp_path / "empty"), "--out", str(tmp_path / "o"))
    assert rc != 0 and "not a contacts data set" in err
    rc, err = tactip("select-markers", str(contacts_folder), "--out", str(tmp_path / "o"),
                     "--tasks", "object,grasp")
    assert rc != 0 and "--tasks='object,grasp'" in err
