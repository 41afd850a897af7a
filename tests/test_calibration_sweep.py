"""Sweeps end to end on a tiny grid at low resolution: round trip, resume, parallel == serial."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import tactip_sim as ts
from tactip_lab.sampling.dataset import TARGET_COLUMNS, Dataset, DatasetError
from tactip_lab.sampling.poses import PoseSet
from tactip_lab.sampling.sweep import SweepSpec, run_sweep

TINY = np.array([[0.0, 0.0, 1.0], [8.0, -4.0, 1.0], [-8.0, -8.0, 0.5], [0.0, 2.0, 1.5],
                 [12.0, 0.0, 1.0], [-4.0, -10.0, 1.0]])


@pytest.fixture(scope="module")
def small_scene(scene):
    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2})


@pytest.fixture(scope="module")
def spec(small_scene):
    # the nominal tip uses the bundled mesh: no re-meshing in the test run
    return SweepSpec(small_scene, "A", PoseSet("tiny", TINY), frames=2, nominal=True)


@pytest.fixture(scope="module")
def serial(spec, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "ds"
    res = run_sweep(spec, out, progress=False, chunk=2)
    assert res.computed == len(TINY)
    return out


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file() and p.suffix in (".png", ".csv")}


def test_dataset_round_trip(serial, spec):
    import os
    import stat

    ds = Dataset(serial)
    umask = os.umask(0)
    os.umask(umask)
    for f in ("targets.csv", "truth.npz", "images/00000.png", "records/00000.npz"):
        # atomic writes go through mkstemp (0600); outside tools must be able to read them
        assert stat.S_IMODE((serial / f).stat().st_mode) == 0o666 & ~umask, f
    with (serial / "targets.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == TARGET_COLUMNS
    assert [f"pose_{k}" for k in range(1, 7)] == TARGET_COLUMNS[2:8]
    assert len(rows) == len(TINY)
    for row, pose in zip(rows, TINY, strict=True):
        # Bristol convention: pose_3 = depth (mm), pose_4 = Rx = roll, pose_5 = Ry = pitch
        assert float(row["pose_3"]) == pose[2] == float(row["depth_mm"])
        assert float(row["pose_4"]) == pose[0] == float(row["roll_deg"])
        assert float(row["pose_5"]) == pose[1] == float(row["pitch_deg"])
        assert (serial / row["image"]).is_file()
    recs = ds.records()
    assert [r.index for r in recs] == list(range(len(TINY)))
    with np.load(serial / "truth.npz") as truth:
        assert truth["markers_mm"].shape == (len(TINY), 97, 3)
        assert truth["markers_px"].shape == (len(TINY), 97, 2)
        np.testing.assert_array_equal(truth["markers_mm"][3], recs[3].markers_mm)
    t = ds.table()
    assert np.all(t["force_N"] > 0) and np.all(t["contact"] == 1)
    # the perceived CoP comes from perception on the frames: finite, inside the image
    assert np.all(np.isfinite(t["cop_area_x_px"])) and np.all((t["cop_area_x_px"] > 0)
                                                         & (t["cop_area_x_px"] < 320))
    assert ds.manifest()["identity"]["tip"] == "A"


def test_resume_after_kill_gives_the_same_dataset(spec, serial, tmp_path):
    out = tmp_path / "ds"

    class Killed(Exception):
        pass

    def kill_after_three(index):
        if index == 2:
            raise Killed

    with pytest.raises(Killed):
        run_sweep(spec, out, progress=False, chunk=1, on_sample=kill_after_three)
    ds = Dataset(out)
    assert ds.done() == {0, 1, 2}
    assert not (out / "targets.csv").exists()
    # leftover temporary files from a torn write are never taken as samples
    (out / "records" / ".00003.npz.tmp").write_bytes(b"torn")
    res = run_sweep(spec, out, progress=False, chunk=1)
    assert res.computed == len(TINY) - 3 and res.skipped == 3
    assert _files(out) == _files(serial)
    # a rerun of a finished sweep computes nothing
    assert run_sweep(spec, out, progress=False).computed == 0


def test_changed_scene_in_existing_folder_is_refused(spec, serial):
    other = SweepSpec(ts.replace_in(spec.scene, gel={"youngs_modulus_kpa": 40.0}), "A",
                      spec.poses, frames=2, nominal=True)
    with pytest.raises(DatasetError, match=r"already holds a different sweep \(scene_hash"):
        run_sweep(other, serial, progress=False)


def test_dataset_of_another_perception_version_is_refused(spec, serial, monkeypatch):
    import perception

    assert Dataset(serial).manifest()["identity"]["perception_results"] == \
        perception.RESULTS_VERSION
    monkeypatch.setattr(perception, "RESULTS_VERSION", perception.RESULTS_VERSION + 1)
    with pytest.raises(DatasetError, match=r"\(perception_results: .*another perception"):
        run_sweep(spec, serial, progress=False)


def test_dataset_of_another_physics_version_is_refused(spec, serial, monkeypatch):
    import tactip_sim.fem

    assert Dataset(serial).manifest()["identity"]["physics_results"] == \
        tactip_sim.fem.RESULTS_VERSION
    monkeypatch.setattr(tactip_sim.fem, "RESULTS_VERSION", tactip_sim.fem.RESULTS_VERSION + 1)
    with pytest.raises(DatasetError, match=r"\(physics_results: .*another version of the FEM"):
        run_sweep(spec, serial, progress=False)


def test_dask_cluster_by_address_is_byte_identical_to_serial(spec, serial, tmp_path):
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster:
        out = tmp_path / "cluster"
        run_sweep(spec, out, scheduler=cluster.scheduler_address, progress=False, chunk=3)
        # the sweep's worker settings reach a cluster it did not start (one OpenCV thread per
        # worker; a worker that joins later gets them too)
        from tactip_lab.sampling.executor import close_client, open_client

        client = open_client(1, cluster.scheduler_address)
        try:
            cluster.scale(3)
            client.wait_for_workers(3, timeout=60)
            assert set(client.run(_opencv_threads).values()) == {1}
        finally:
            close_client(client)
    assert _files(out) == _files(serial)


def _worker_timers(dask_worker) -> tuple[bool, float, float]:
    cbs = dask_worker.periodic_callbacks
    return "profile" in cbs, cbs["tick"].callback_time, cbs["monitor"].callback_time


def test_local_cluster_workers_sample_their_diagnostics_slowly(spec, serial, tmp_path):
    """The clusters ``--workers N`` starts do not profile their tasks' stacks every 10 ms nor
    wake their event loop every 20 ms (QUIET_WORKERS); this process's settings stay as they
    were, and the sweep's files (written by the workers themselves) are the serial run's.
    (The cluster a sweep opens itself, ``run_sweep(workers=2)``, is the same ``open_client(2,
    None)``; it gives the serial bytes in test_every_worker_computes_with_the_mesh_of_the_spec.)"""
    import dask

    from tactip_lab.sampling.executor import close_client, open_client

    before = dask.config.get("distributed.worker.profile.enabled")
    client = open_client(2, None)
    try:
        timers = set(client.run(_worker_timers).values())
        out = tmp_path / "local"
        run_sweep(spec, out, client=client, progress=False, chunk=2)
    finally:
        close_client(client)
    assert timers == {(False, 1000.0, 2000.0)}  # ms: the defaults are a profile, 20 and 500
    assert dask.config.get("distributed.worker.profile.enabled") == before
    assert _files(out) == _files(serial)


def _opencv_threads() -> int:
    import cv2

    return cv2.getNumThreads()


_FAULTS = """
import resource, sys
import numpy as np
if sys.argv[1] == "steady":
    from tactip_lab.sampling.dask_setup import steady_allocator
    assert steady_allocator()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):  # warm the heap
    np.ones(153600)
before = faults()
for _ in range(40):  # a frame-sized array (640 x 480 float32 = 1.2 MB) made and freed, 40 times
    np.ones(153600)
print(faults() - before)
"""


def test_steady_allocator_stops_page_faults_under_dasks_trim_setting():
    """Under Dask's nanny setting (MALLOC_TRIM_THRESHOLD_=65536) every frame-sized array is a
    fresh mmap: a page fault per 4 kB page of every new array (arrays below 2 MB, so no
    transparent huge page hides them). With the steady allocator the heap is reused and the
    faults vanish (measured here: ~300 per array without, none with)."""
    import os
    import platform
    import subprocess
    import sys

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("the allocator settings are glibc's")
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    counts = {mode: int(subprocess.run([sys.executable, "-c", _FAULTS, mode], env=env,
                                       capture_output=True, text=True, check=True).stdout)
              for mode in ("plain", "steady")}
    assert counts["plain"] > 40 * 200  # the trap: each array faults its 300 pages in anew
    assert counts["steady"] < counts["plain"] / 20


_POOLS = """
import drjit, threadpoolctl
import scipy.linalg  # loads SciPy's own OpenBLAS beside NumPy's
from tactip_lab.sampling.dask_setup import one_thread_pools
before = max(d["num_threads"] for d in threadpoolctl.threadpool_info())
one_thread_pools()
after = [d["num_threads"] for d in threadpoolctl.threadpool_info()]
print(before, max(after), len(after), drjit.thread_count())
"""


def test_worker_thread_pools_are_one_thread_each():
    """A sweep worker's parallelism is its task slot: its BLAS pools (NumPy's and SciPy's) and
    Dr.Jit's are cut to one thread (on this 2-core machine they start with two each)."""
    import os
    import subprocess
    import sys

    from .conftest import ROOT

    done = subprocess.run([sys.executable, "-c", _POOLS], capture_output=True, text=True,
                          check=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    before, after, pools, drjit_threads = (int(v) for v in done.stdout.split())
    assert pools >= 1 and after == 1 and drjit_threads == 1
    if (os.cpu_count() or 1) > 1 and "OPENBLAS_NUM_THREADS" not in os.environ:
        assert before > 1  # the default the workers had: a thread per core


def test_interrupt_warnings_are_dropped_and_nothing_else():
    import logging

    from tactip_lab.sampling.dask_setup import (
        EXPECTED_ON_INTERRUPT,
        QuietInterrupt,
        quiet_interrupt,
    )

    for name, fragment in EXPECTED_ON_INTERRUPT.items():
        quiet_interrupt(name)
        quiet_interrupt(name)  # once per process
        log = logging.getLogger(name)
        assert sum(isinstance(f, QuietInterrupt) for f in log.filters) == 1

        def record(msg, log=log):
            return log.makeRecord(log.name, logging.WARNING, __file__, 1, msg, (), None)

        assert not log.filter(record(f"Async instruction for <Task> {fragment} x"))
        assert log.filter(record("Worker exceeded 95% memory budget"))


def test_every_worker_computes_with_the_mesh_of_the_spec(small_scene, tmp_path):
    """The tip's mesh is resolved once and travels with the spec: pytetwild gives a different
    mesh on every build, and workers that each built (or loaded) their own would compute one
    tip with different meshes. A mesh that no cache holds (the bundled one with its interior
    nodes moved) must give 2 workers the serial run's bytes, differ from the bundled mesh's
    results, and be refused when a resume brings another mesh."""
    from dataclasses import replace

    scene = ts.replace_in(small_scene, fidelity={"element_order": 1})  # cheap compliance
    base = SweepSpec(scene, "A", PoseSet("mesh", TINY[:4]), frames=1, nominal=True).with_mesh()
    odd = replace(base, mesh=_another_instance(base.mesh, seed=0))
    run_sweep(odd, tmp_path / "serial", progress=False, chunk=1)
    run_sweep(odd, tmp_path / "workers", workers=2, progress=False, chunk=1)
    run_sweep(base, tmp_path / "bundled", progress=False, chunk=2)
    assert _files(tmp_path / "workers") == _files(tmp_path / "serial")
    assert _files(tmp_path / "bundled") != _files(tmp_path / "serial")
    with pytest.raises(DatasetError, match="mesh_digest.*tet mesh differs"):
        run_sweep(base, tmp_path / "serial", progress=False)


def test_a_sweep_resumes_with_the_mesh_its_dataset_keeps(small_scene, tmp_path):
    """pytetwild builds another mesh in every checkout's cache, so a sweep begun elsewhere
    used to be refused on resume (mesh_digest). The dataset keeps its mesh: a spec that names
    no mesh resumes with it (not the bundled one) and ends with the uninterrupted run's
    bytes; a kept file that is damaged or meshed for another scene is named."""
    from dataclasses import replace

    from tactip_sim.mesh import MeshKeyError, read_mesh

    scene = ts.replace_in(small_scene, fidelity={"element_order": 1})  # cheap compliance
    base = SweepSpec(scene, "A", PoseSet("kept", TINY[:3]), frames=1, nominal=True)
    m = base.with_mesh().mesh
    built_elsewhere = replace(base, mesh=_another_instance(m, seed=1))
    run_sweep(built_elsewhere, tmp_path / "whole", progress=False, chunk=1)

    class Killed(Exception):
        pass

    def kill(index):
        if index == 0:
            raise Killed

    out = tmp_path / "resumed"
    with pytest.raises(Killed):
        run_sweep(built_elsewhere, out, progress=False, chunk=1, on_sample=kill)
    kept = Dataset(out).stored_mesh(scene)
    assert kept.digest == built_elsewhere.mesh.digest != m.digest
    res = run_sweep(base, out, progress=False, chunk=1)  # base names no mesh
    assert res.computed == 2 and res.skipped == 1
    assert _files(out) == _files(tmp_path / "whole")

    other = ts.replace_in(scene, skin={"thickness_mm": 1.5})  # another pad: another mesh key
    assert Dataset(out).stored_mesh(other) is None  # another sweep's: the identity names it
    with pytest.raises(MeshKeyError, match="built for another scene.*mesh key"):
        read_mesh(out / "mesh.npz", other)
    (out / "mesh.npz").write_bytes(b"torn")
    with pytest.raises(DatasetError, match=r"mesh\.npz is unreadable.*new --out"):
        run_sweep(base, out, progress=False)


def _another_instance(mesh, *, seed: int):
    """``mesh`` with its interior nodes moved (up to ~0.1 mm): a mesh no cache or bundle
    holds, as another pytetwild build would be."""
    from tactip_sim.mesh import TetMesh

    interior = np.ones(len(mesh.nodes), bool)
    interior[np.unique(_boundary_nodes(mesh.tets))] = False
    nodes = mesh.nodes.copy()
    nodes[interior] += np.random.default_rng(seed).normal(0, 0.05, (interior.sum(), 3))
    return TetMesh(nodes, mesh.tets, mesh.regions, mesh.key, 0.0)


def _boundary_nodes(tets):
    """Nodes on faces that belong to one tet only."""
    faces = np.sort(np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]],
                                    tets[:, [1, 2, 3]]]), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    return uniq[count == 1].ravel()


def test_warm_up_builds_the_worker_the_sweep_uses(spec, tmp_path):
    """A benchmark warms the chain up before timing the sweep; the sweep must find that very
    chain (same key, mesh included), not build a second one inside the timed part."""
    from tactip_lab.sampling.sweep import chain_for, warm_up

    warm_up(spec)
    warm = chain_for(spec.with_mesh())
    run_sweep(spec, tmp_path / "ds", progress=False, limit=1)
    assert chain_for(spec.with_mesh()) is warm


def test_format_1_datasets_still_read_and_refuse_a_resume(tmp_path, spec):
    """A dataset written before the centre-of-pressure columns were renamed (format 1) reads
    with its values under the new names, and a sweep will not append to it."""
    import json

    from tactip_lab.fitting.fit import features
    from tactip_lab.sampling.dataset import FORMAT_1_NAMES

    old_name = {new: old for old, new in FORMAT_1_NAMES.items()}
    header = [old_name.get(c, c) for c in TARGET_COLUMNS]
    assert "cop_ac_x_px" in header and "cop_x_px" in header
    rows = []
    for i in range(4):
        row = dict.fromkeys(header, "0")
        row.update({"index": str(i), "image": f"images/{i:05d}.png", "tip": "A",
                    "roll_deg": str(2.0 * i), "pitch_deg": str(-1.0 * i), "depth_mm": "1.0",
                    "cop_x_px": str(100.0 + i), "cop_y_px": "50", "cop_ac_x_px": str(200.0 + i),
                    "cop_ac_y_px": "60"})
        rows.append(",".join(row[c] for c in header))
    root = tmp_path / "old"
    root.mkdir()
    (root / "targets.csv").write_text(",".join(header) + "\n" + "\n".join(rows) + "\n")
    (root / "manifest.json").write_text(json.dumps(
        {"kind": "tactip-sim dataset", "format_version": 1, "identity": {},
         "scene": {"camera": {"resolution": [320, 240]}}}))
    growth = features(root, feature="growth")
    np.testing.assert_array_equal(growth.cop_px[:, 0], [200.0, 201.0, 202.0, 203.0])
    np.testing.assert_array_equal(features(root, feature="area").cop_px[:, 0],
                                  [100.0, 101.0, 102.0, 103.0])
    np.testing.assert_array_equal(growth.angles_deg[:, 0], [0.0, 2.0, 4.0, 6.0])
    with pytest.raises(DatasetError, match="dataset format 1.*renamed"):
        run_sweep(spec, root, progress=False)
    with pytest.raises(ValueError, match="feature='area_change' is not allowed"):
        features(root, feature="area_change")


def test_a_resume_removes_orphaned_half_written_files_only(spec, tmp_path):
    """A worker killed mid-write leaves ``.NNNNN.npz.XXXX.tmp``: a resume removes such files
    older than STALE_TMP_S and leaves younger ones (a writer may still be at work) and every
    other file."""
    import os
    import time

    from tactip_lab.sampling.dataset import STALE_TMP_S

    out = tmp_path / "ds"
    run_sweep(spec, out, progress=False)
    old_time = time.time() - 2 * STALE_TMP_S
    stale = [out / "records" / ".00003.npz.abc123.tmp", out / "images" / ".00004.png.x1.tmp",
             out / "images" / ".rest.png.q9.tmp"]
    fresh = out / "records" / ".00005.npz.def456.tmp"
    mine = out / "records" / "notes.tmp"  # not a name the tool gives its files
    for p in [*stale, fresh, mine]:
        p.write_bytes(b"PK")
    for p in [*stale, mine]:
        os.utime(p, (old_time, old_time))
    good = _files(out)
    assert Dataset(out).done() == set(range(6))
    assert not any(p.exists() for p in stale)
    assert fresh.exists() and mine.exists()
    assert run_sweep(spec, out, progress=False).computed == 0
    assert _files(out) == good


def test_damaged_samples_are_recomputed_and_damaged_tables_refused(spec, tmp_path):
    """A resume recomputes a sample whose record is torn or whose image is missing or
    empty; a truncated or duplicated targets.csv is refused, not used."""
    from tactip_lab.fitting.fit import features

    out = tmp_path / "ds"
    run_sweep(spec, out, progress=False)
    good = _files(out)
    ds = Dataset(out)
    ds.record_path(1).write_bytes(ds.record_path(1).read_bytes()[:50])  # torn
    ds.image_path(2).unlink()  # missing
    ds.image_path(3).write_bytes(b"")  # empty
    assert ds.done() == {0, 4, 5}
    res = run_sweep(spec, out, progress=False)
    assert res.computed == 3 and _files(out) == good
    table = (out / "targets.csv").read_text().splitlines()
    (out / "targets.csv").write_text("\n".join(table[:4]) + "\n")  # 3 of 6 samples
    with pytest.raises(DatasetError, match="holds 3 samples but the manifest says 6"):
        features(out)
    (out / "targets.csv").write_text("\n".join(table + table[-1:]) + "\n")
    with pytest.raises(DatasetError, match="duplicated sample rows"):
        features(out)


def test_a_sweep_that_failed_before_computing_anything_does_not_block_the_fix(spec, tmp_path):
    from dataclasses import replace

    out = tmp_path / "ds"
    broken = replace(spec, scene=ts.replace_in(spec.scene, camera={"distance_mm": 0.5}))
    with pytest.raises(ValueError):
        run_sweep(broken, out, progress=False)  # the camera sits in the window: refused
    assert (out / "manifest.json").is_file() and Dataset(out).done() == set()
    res = run_sweep(spec, out, progress=False, limit=1)  # the corrected rerun starts afresh
    assert res.computed == 1


def test_calibrate_refuses_unsafe_tip_names_and_a_feature_switch(scene, tmp_path):
    import json

    from tactip_lab.protocol.calibrate import calibrate

    for bad in ("x/../../../ESCAPED", "..", "", "a b"):
        with pytest.raises(ValueError, match="tip="):
            calibrate(scene, tmp_path / "cal", tips=[bad], progress=False)
    with pytest.raises(ValueError, match="tips=\\[\\] is not allowed"):
        calibrate(scene, tmp_path / "cal", tips=[], progress=False)
    assert not (tmp_path / "cal").exists() and not (tmp_path / "ESCAPED").exists()
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "manifest.json").write_text(json.dumps({"feature": "growth"}))
    with pytest.raises(ValueError, match="holds a calibration with --feature growth"):
        calibrate(scene, tmp_path / "cal", feature="area", progress=False)


def test_runs_json_counts_every_written_sample_without_a_clean_exit(tmp_path):
    """A SIGKILL runs no handler: the count on disk must already be right after each
    sample (the log is rewritten per sample)."""
    import json

    from tactip_lab.sampling.runlog import RunLog

    log = RunLog(tmp_path / "runs.json", frames=60)
    for i in range(7):
        log.tick(i)
    # no flush(), no finish(): read what a killed process would have left
    (entry,) = json.loads((tmp_path / "runs.json").read_text())
    assert entry["samples_computed"] == 7 and not entry["finished"]


def test_a_resume_with_another_tip_names_the_tip_not_the_mesh(spec, serial):
    from dataclasses import replace

    other = replace(spec, tip="B", nominal=False)  # a manufactured tip B: another mesh too
    with pytest.raises(DatasetError, match="already holds a different sweep \\(tip: 'A' there"):
        run_sweep(other, serial, progress=False)
