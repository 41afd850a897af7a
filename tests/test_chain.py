"""One chain: a calibration sweep, a fidelity-study level and a stability-map point run the same
press -> render -> noise -> perceive code, so the same scene, pose and seed key give the same
features, byte for byte; and the one marker-identity rule on known layouts."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_lab.sampling.chain import MATCH_FRACTION, Chain, identify_markers, set_tag
from tactip_lab.sampling.dataset import SampleRecord
from tactip_lab.sampling.poses import PoseSet
from tactip_lab.sampling.sweep import SweepSpec, run_sweep
from tactip_lab.studies.fidelity import Level, LevelRunner
from tactip_lab.studies.stability import Rig

POSES = np.array([[6.0, -3.0, 1.0], [-10.0, -8.0, 0.5]])


@pytest.fixture(scope="module")
def small_scene(scene):
    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2}, protocol={"frames_per_sample": 2})


@pytest.fixture(scope="module")
def swept(small_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("chain") / "probe"
    run_sweep(SweepSpec(small_scene, "A", PoseSet("probe", POSES), frames=2, nominal=True),
              out, progress=False)
    return [SampleRecord.from_npz(out / "records" / f"{i:05d}.npz") for i in range(len(POSES))]


def test_sweep_fidelity_level_and_stability_point_give_identical_features(small_scene, swept):
    as_is = Level("as is", "preset", {})  # the scene itself, no preset applied
    runner = LevelRunner(as_is.scene(small_scene), tuple(small_scene.camera.resolution), {},
                         frames_cap=None)
    level = runner.run(POSES, "probe")
    rig = Rig(small_scene, frames=2)
    for i, rec in enumerate(swept):
        obs, _ = rig.sample(rig.press(POSES[i]), "probe", i)
        # the growth-weighted CoP: the feature all three use
        assert rec.cop_growth_px.tobytes() == level.cop_px[i].tobytes() == obs.cop.tobytes()
        assert rec.markers_mm.tobytes() == level.markers_mm[i].tobytes()
        assert np.all(np.isfinite(rec.cop_growth_px))
    # and the seed key matters: another index is another noise draw, other features
    other = Chain.for_tip(small_scene, "A", nominal=True).sample(POSES[0], set_tag("probe"), 1)
    assert other.perceived.cop_growth.tobytes() != swept[0].cop_growth_px.tobytes()
    assert other.state.force_N == swept[0].force_N  # the same press


def test_chain_rest_markers_map_one_to_one_onto_pins(scene):
    chain = Chain.for_tip(scene, "A", nominal=True, frames=1)
    pins = chain.pin_of[chain.pin_of >= 0]
    assert len(np.unique(pins)) == len(pins)  # one-to-one
    # at the default 640x480 every pin the camera sees at rest is found on the rest frame
    _, visible, _ = chain.truth(None)
    assert len(pins) == int(visible.sum()) == scene.pins.count
    # a pressed sample's perceived pins sit near their own analytic cap images
    s = chain.sample((0.0, -4.0, 1.0), set_tag("near"), 0)
    err = np.linalg.norm(s.pins_px - s.rendered.blobs_px, axis=1)
    assert np.nanmedian(err) < 0.5


def test_identify_markers_known_layout():
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [np.nan, np.nan]])
    spacing = 10.0
    gate = MATCH_FRACTION * spacing  # 2.5 px
    rest = np.array([[10.4, 0.3],     # pin 1
                     [0.2, -1.0],     # pin 0
                     [0.0, 1.5],      # also nearest pin 0, but farther: spurious
                     [20.0, gate + 0.1],  # beyond the gate: spurious
                     [50.0, 0.0]])    # nowhere near
    assert identify_markers(rest, truth, spacing).tolist() == [1, 0, -1, -1, -1]
    assert identify_markers(np.zeros((0, 2)), truth, spacing).tolist() == []
