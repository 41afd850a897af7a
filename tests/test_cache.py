"""The on-disk cache deletes only what it wrote, and never trusts what it reads."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim import cache

from .conftest import SCENES


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("TACTIP_CACHE_DIR", str(d))
    return d


def test_clear_on_a_users_folder_removes_only_the_tools_entries(tmp_path, monkeypatch):
    users = tmp_path / "thesis"
    (users / "compliance").mkdir(parents=True)
    (users / "thesis.txt").write_text("three years of work")
    (users / "compliance" / "notes.txt").write_text("mine")
    (users / "figures").mkdir()
    (users / "figures" / "fig1.npz").write_bytes(b"not the tool's")
    monkeypatch.setenv("TACTIP_CACHE_DIR", str(users))
    cache.save_npz(cache.path_for("compliance", "abc", ".npz"), compliance=np.eye(3))
    cache.save_npz(cache.path_for("mesh", "m1", ".npz"), nodes=np.zeros((4, 3)))
    assert len(cache.entries()) == 3  # two entries and the cache tag
    d, n = cache.clear()
    assert (d, n) == (users, 3)
    assert (users / "thesis.txt").read_text() == "three years of work"
    assert (users / "compliance" / "notes.txt").read_text() == "mine"
    assert (users / "figures" / "fig1.npz").read_bytes() == b"not the tool's"
    assert not (users / "mesh").exists()  # emptied and removed: it was the tool's
    assert cache.entries() == []


def test_clear_removes_an_own_cache_entirely(own_cache):
    cache.save_npz(cache.path_for("marker_response", "k", ".npz"), response=np.ones((2, 3)))
    cache.clear()
    assert not own_cache.exists()


@pytest.mark.parametrize("damage", ["truncated", "zeroed", "nan", "not_npz", "no_digest"])
def test_a_damaged_entry_is_reported_removed_and_not_used(own_cache, damage):
    path = cache.path_for("compliance", "key", ".npz")
    good = np.arange(12.0).reshape(3, 4)
    cache.save_npz(path, compliance=good)
    np.testing.assert_array_equal(cache.load_npz(path, ["compliance"])["compliance"], good)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:100])
    elif damage == "zeroed":  # a valid file whose numbers were changed after the fact
        with np.load(path) as d:
            arrays = dict(d)
        arrays["compliance"] = np.zeros_like(good)
        np.savez(path, **arrays)
    elif damage == "nan":
        bad = good.copy()
        bad[1, 2] = np.nan
        cache.save_npz(path, compliance=bad)
    elif damage == "not_npz":
        path.write_text("hello")
    else:  # written by a version without digests
        np.savez(path, compliance=good)
    with pytest.warns(cache.CacheWarning, match="unusable"):
        assert cache.load_npz(path, ["compliance"]) is None
    assert not path.exists()


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="not a cache kind"):
        cache.path_for("../../etc", "x", ".npz")


def test_a_corrupt_compliance_is_rebuilt_to_the_same_answer(own_cache):
    scene = ts.load_scene(SCENES / "shadow_fingertip.toml")
    pose = ts.Pose(roll_deg=4, pitch_deg=-2, depth_mm=1.0)
    first = ts.Simulator(scene, element_order=1).press(pose)
    (entry,) = [p for p in own_cache.glob("compliance/*.npz") if "bounds" not in p.name]
    entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])  # torn by hand
    with pytest.warns(cache.CacheWarning, match="unreadable"):
        again = ts.Simulator(scene, element_order=1).press(pose)
    np.testing.assert_array_equal(again.markers_mm, first.markers_mm)
    assert again.force_N == first.force_N > 0
