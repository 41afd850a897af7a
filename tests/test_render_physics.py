"""Frames of pressed pads (FEM marker positions): centroids against the analytic truth."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Camera, Criteria, resolvable, visibility

from .test_render_frame import measured, rms


@pytest.fixture(scope="module")
def sim(scene):
    return ts.Simulator(scene)


def check_pose(sim, scene, roll: float, pitch: float, depth: float, rng: int) -> tuple[int, float]:
    state = sim.press(ts.Pose(roll, pitch, depth))
    frame = sim.render(state, rng=rng)
    m, d = state.markers_mm, state.marker_directions
    assert np.max(np.linalg.norm(m - sim.pad.markers_mm, axis=1)) > 0.1  # pressed, not at rest
    camera = Camera.from_scene(scene)
    assert np.allclose(frame.markers_px, camera.project(m))
    vis = visibility(camera, sim.pad, m, d)
    assert np.array_equal(frame.visible, vis.visible)
    _, diam, outline = camera.cap_images(m, d, scene.pins.marker_diameter_mm / 2)
    ok, _ = resolvable(camera, vis, diam, outline, Criteria.from_scene(scene))
    got, found = measured(frame)
    assert found[ok].all(), f"pose ({roll}, {pitch}, {depth}): resolvable markers missed"
    return int(ok.sum()), rms((got - frame.blobs_px)[ok])


@pytest.mark.parametrize(("roll", "pitch"), [(0.0, 0.0), (-16.0, -11.0), (16.0, 3.0)])
def test_pressed_frames_match_the_truth(sim, scene, roll, pitch):
    n_ok, err = check_pose(sim, scene, roll, pitch, scene.protocol.training_depth_mm, rng=1)
    assert n_ok >= 70  # pressing crowds the outer ring: some caps come within a blur width
    assert err <= 0.1


@pytest.mark.slow
def test_whole_calibration_grid(sim, scene):
    p = scene.protocol
    rolls = np.arange(p.roll_range_deg[0], p.roll_range_deg[1] + 1e-9, p.roll_step_deg)
    pitches = np.arange(p.pitch_range_deg[0], p.pitch_range_deg[1] + 1e-9, p.pitch_step_deg)
    errors, counts = [], []
    for i, roll in enumerate(rolls):
        for j, pitch in enumerate(pitches):
            n_ok, err = check_pose(sim, scene, float(roll), float(pitch), p.training_depth_mm,
                                   rng=100 * i + j)
            counts.append(n_ok)
            errors.append(err)
    assert len(errors) == len(rolls) * len(pitches) == 255
    assert np.sqrt(np.mean(np.square(errors))) <= 0.1
    assert max(errors) <= 0.15
    assert min(counts) >= 70
