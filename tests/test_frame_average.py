"""``protocol.frame_average``: a sample's frames averaged pixel by pixel, perceived once."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.render.noise import MEAN_SCALE, mean_frame
from tactip_sim.scene import SceneError, replace_in, scene_hash

from .conftest import SCENES


def test_mean_frame_is_the_pixel_mean_in_16_bits():
    a = np.full((3, 4), 10, np.uint8)
    b = np.full((3, 4), 12, np.uint8)
    b[0, 0] = 255
    m = mean_frame([a, b])
    assert m.dtype == np.uint16
    assert m[1, 1] == 11 * 257 and m[0, 0] == round(132.5 * 257)  # 34052.5 -> even: 34052
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (5, 7), dtype=np.uint8) for _ in range(60)]
    exact = np.mean(np.stack(frames).astype(np.float64), axis=0) * MEAN_SCALE
    assert np.max(np.abs(mean_frame(frames) - exact)) <= 0.5 + 1e-3
    assert mean_frame([np.full((2, 2), 255, np.uint8)] * 3).max() == 65535
    with pytest.raises(ValueError, match="at least one frame"):
        mean_frame([])


def test_the_image_mean_is_the_default_and_the_key_is_checked():
    scene = ts.load_scene(SCENES / "shadow_fingertip.toml")
    assert scene.protocol.frame_average == "image"
    assert scene_hash(replace_in(scene, protocol={"frame_average": "image"})) == \
        scene_hash(scene)
    assert scene_hash(replace_in(scene, protocol={"frame_average": "features"})) != \
        scene_hash(scene)
    with pytest.raises(SceneError, match="protocol.frame_average"):
        replace_in(scene, protocol={"frame_average": "median"})


def test_image_mean_perceives_the_markers_and_cop_of_the_frame_by_frame_average():
    """One pose, 60 frames, both averaging orders: the mean image's markers sit on the
    analytic cap centroids as closely as the frame-by-frame average's, and the two CoPs
    agree to a small fraction of a pixel (the noise of 60 frames is ~0.02 px on a CoP)."""
    from tactip_lab.sampling.chain import Chain, set_tag

    base = ts.load_scene(SCENES / "shadow_fingertip.toml")
    out = {}
    for mode in ("features", "image"):
        scene = replace_in(base, protocol={"frame_average": mode})
        chain = Chain.for_tip(scene, "A", nominal=True, frames=60)
        s = chain.sample((6.0, -4.0, 1.0), set_tag("average"), 0)
        ok = np.isfinite(s.pins_px).all(axis=1)
        err = np.linalg.norm(s.pins_px[ok] - s.rendered.blobs_px[ok], axis=1)
        out[mode] = (s, err)
    img, feat = out["image"][0], out["features"][0]
    assert len(img.rendered.images) == 1 and img.rendered.images[0].dtype == np.uint16
    assert len(feat.rendered.images) == 60
    e_img, e_feat = out["image"][1], out["features"][1]
    assert len(e_img) == len(e_feat) >= 90
    assert np.sqrt(np.mean(e_img**2)) < 1.2 * np.sqrt(np.mean(e_feat**2)) + 0.01
    for name in ("cop_area", "cop_growth", "cop_hull"):
        a, b = getattr(img.perceived, name), getattr(feat.perceived, name)
        assert np.linalg.norm(a - b) < 0.1, (name, a, b)


def test_recognition_images_of_a_frame_mean_are_on_the_rest_frames_8_bit_scale():
    # object recognition differences contact images against the (8-bit) rest frame: a 16-bit
    # frame mean must come back on the same scale
    from tactip_lab.recognition.contacts import downsample

    rng = np.random.default_rng(1)
    frame = rng.integers(0, 256, (48, 64), dtype=np.uint8)
    mean = mean_frame([frame, frame])
    assert mean.dtype == np.uint16
    small = downsample(mean, (16, 12))
    assert small.dtype == np.uint8
    assert np.array_equal(small, downsample(frame, (16, 12)))
