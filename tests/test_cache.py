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
    # a build lock a killed builder left behind (the lock itself died with it)
    (users / "compliance" / "abc.npz.lock").touch()
    assert len(cache.entries()) == 4  # two entries, the lock file and the cache tag
    d, n = cache.clear()
    assert (d, n) == (users, 4)
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


# A builder racing another process for one entry: each writes different numbers (seeded by
# its index), so the two agree only if one built and the other loaded what it wrote.
_RACER = """
import sys, time
from pathlib import Path

import numpy as np

from tactip_sim import cache

go, index = Path(sys.argv[1]), int(sys.argv[2])
path = cache.path_for("compliance", "race", ".npz")
Path(f"{go}.ready{index}").touch()
while not go.exists():
    time.sleep(0.002)
with cache.build_lock(path):
    got = cache.load_npz(path, ["compliance"])
    if got is None:
        time.sleep(0.5)  # a build far longer than the two starts' skew
        got = {"compliance": np.random.default_rng(index).random((4, 4))}
        cache.save_npz(path, **got)
        print("built", end=" ")
print(repr(float(got["compliance"].sum())))
"""


def test_two_processes_racing_for_an_entry_build_it_once(own_cache, tmp_path):
    """Two processes released at once to look up and build the same missing entry: one
    builds it, the other waits and loads it (without the lock both find it missing and
    both build, each its own numbers); the lock file is gone afterwards."""
    import os
    import subprocess
    import sys
    import time

    go = tmp_path / "go"
    env = {**os.environ, "TACTIP_CACHE_DIR": str(own_cache)}
    procs = [subprocess.Popen([sys.executable, "-c", _RACER, str(go), str(i)], env=env,
                              stdout=subprocess.PIPE, text=True) for i in (1, 2)]
    deadline = time.monotonic() + 60
    while not all((tmp_path / f"go.ready{i}").exists() for i in (1, 2)):
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs)
        time.sleep(0.005)
    go.touch()
    outs = [p.communicate(timeout=60)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sorted(len(o) for o in outs) == [1, 2]  # one "built <sum>", one "<sum>"
    assert outs[0][-1] == outs[1][-1]
    assert sorted(p.name for p in cache.entries()) == ["CACHEDIR.TAG", "race.npz"]


def test_a_compliance_wanted_twice_at_once_is_built_once(own_cache):
    """Two reduced models of one body made at the same time (threads: the lock is per open
    file, so it holds between them as between processes): one builds the compliance, the
    other waits and loads it, and both hold the same numbers."""
    from concurrent.futures import ThreadPoolExecutor

    from tactip_sim.fem.linear.reduced import ReducedModel

    body = ts.Simulator(ts.load_scene(SCENES / "shadow_fingertip.toml"), element_order=1).body
    body.markers  # noqa: B018 - built before the race (the models share the body)
    with ThreadPoolExecutor(2) as pool:
        models = list(pool.map(lambda _: ReducedModel(body), range(2)))
    assert sorted(m.from_cache for m in models) == [False, True]
    np.testing.assert_array_equal(models[0].compliance, models[1].compliance)
    np.testing.assert_array_equal(models[0].marker_response_t, models[1].marker_response_t)
    assert not list(own_cache.rglob("*.lock"))
