"""The rig model: its file's checks, its draws (seeded, independent per source), the zero found
by the contact threshold, and a sweep that labels commanded poses but presses reached ones."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_lab.rig.sources import RigModel, find_zero
from tactip_lab.sampling.chain import Chain
from tactip_lab.sampling.poses import PoseSet
from tactip_lab.sampling.sweep import SweepSpec, run_sweep

from .conftest import ROOT


def test_the_shipped_rig_file_cites_every_magnitude():
    rig = RigModel.from_file(ROOT / "rigs" / "pestell_ur5.toml")
    assert not rig.ideal
    cited = dict(rig.sources)
    for key in ("pose_depth_sd_mm", "pose_angle_sd_deg", "zero_step_mm", "exposure_drift_sd"):
        assert getattr(rig, key) > 0 and len(cited[key]) > 20


@pytest.mark.parametrize(("text", "pattern"), [
    ("[rig]\npose_depth_sd_mm = -1\n", r"rig\.pose_depth_sd_mm=-1 is out of range"),
    ("[rig]\nspeed = 3\n", r"unknown key rig\.speed"),
    ("[rig]\nzero_step_mm = 0.1\n", r"rig\.zero_step_mm is not zero but \[rig\.sources\]"),
    ("nothing = 1\n", r"has no \[rig\] table"),
    ("[rig\n", r"cannot be read as TOML"),
])
def test_bad_rig_files_name_the_key(tmp_path, text, pattern):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=pattern):
        RigModel.from_file(path)


def test_draws_are_seeded_and_each_source_switches_alone():
    full = RigModel(pose_depth_sd_mm=0.05, pose_angle_sd_deg=0.5, exposure_drift_sd=0.01)
    no_angle = RigModel(pose_depth_sd_mm=0.05, exposure_drift_sd=0.01)
    pose = np.array([4.0, -2.0, 1.0])
    a, ga = full.perturb(pose, full.rng(0, "A", "train", 3))
    b, gb = full.perturb(pose, full.rng(0, "A", "train", 3))
    np.testing.assert_array_equal(a, b)
    c, gc = no_angle.perturb(pose, no_angle.rng(0, "A", "train", 3))
    np.testing.assert_array_equal(c[:2], pose[:2])  # the angle source off: exact angles
    assert c[2] == a[2] and gc == ga  # the others unchanged by switching it off
    reached = np.array([full.perturb(pose, full.rng(0, "A", "t", i))[0] for i in range(4000)])
    sd = reached.std(axis=0)
    np.testing.assert_allclose(sd, [0.5, 0.5, 0.05], rtol=0.05)
    np.testing.assert_allclose(reached.mean(axis=0), pose, atol=0.03)


def test_zero_found_by_the_threshold_is_where_the_perceived_deformation_crosses_it(scene):
    small = ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                          imaging={"spp": 2})
    chain = Chain.for_tip(small, "A", nominal=True, frames=1)
    step = 0.05
    zero = find_zero(chain, step)
    assert zero > 0 and round(zero / step, 9) == round(zero / step)  # a whole step
    # one step shallower the perceived deformation is below the detector's threshold
    on = chain.pipeline.contact_detector.on_threshold_px
    for depth, above in ((zero - step, False), (zero, True)):
        if depth <= 0:
            continue
        s = chain.sample((0.0, 0.0, depth), 0x2E50, int(round(depth / step)))
        chain.pipeline.reset()
        assert (chain.pipeline.process(s.rendered.images[0]).deformation_px > on) == above
    assert find_zero(chain, 0.0) == 0.0


def test_a_sweep_labels_commanded_poses_and_presses_reached_ones(scene, tmp_path):
    small = ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                          imaging={"spp": 2})
    poses = np.array([[4.0, -2.0, 1.0], [-6.0, -5.0, 1.0]])
    rig = RigModel(pose_angle_sd_deg=1.0, exposure_drift_sd=0.05,
                   sources=(("pose_angle_sd_deg", "test"), ("exposure_drift_sd", "test")))
    ideal = run_sweep(SweepSpec(small, "A", PoseSet("p", poses), frames=1, nominal=True),
                      tmp_path / "ideal", progress=False).dataset.records()
    real = run_sweep(SweepSpec(small, "A", PoseSet("p", poses), frames=1, nominal=True, rig=rig),
                     tmp_path / "rig", progress=False).dataset.records()
    for i, (a, b) in enumerate(zip(ideal, real, strict=True)):
        assert (a.roll_deg, a.pitch_deg) == (b.roll_deg, b.pitch_deg) == tuple(poses[i, :2])
        np.testing.assert_array_equal(a.reached_pose, poses[i])
        assert np.abs(b.reached_pose[:2] - poses[i, :2]).max() > 1e-3  # moved by the rig
        assert b.force_N != a.force_N
