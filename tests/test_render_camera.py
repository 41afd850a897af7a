"""The camera model (exposure, vignetting, blur, noise) and the blob centroids, on synthetic
images with known answers (no Mitsuba)."""

from __future__ import annotations

import numpy as np
import pytest

from tactip_sim.render import CameraModel, blob_centroids, match_blobs
from tactip_sim.render.noise import FULL_SCALE_RADIANCE


def disc_image(centres: np.ndarray, radius: float, shape=(120, 160), level=1.0,
               oversample: int = 8) -> np.ndarray:
    """Exact-coverage discs (box-filtered by oversampling), OpenCV pixel centres."""
    h, w = shape
    s = oversample
    y, x = np.mgrid[0:h * s, 0:w * s]
    x = (x + 0.5) / s - 0.5
    y = (y + 0.5) / s - 0.5
    img = np.zeros((h * s, w * s))
    for cx, cy in centres:
        img[(x - cx) ** 2 + (y - cy) ** 2 <= radius**2] = level
    return img.reshape(h, s, w, s).mean(axis=(1, 3))


def test_exposure_and_quantisation():
    cam = CameraModel(exposure=1.0, read_noise=0, shot_noise=0, blur_px=0, vignetting=0,
                      principal_point_px=(1.5, 1.5))
    img = np.array([[0.0, 0.25, 0.5, 2.0]]) * FULL_SCALE_RADIANCE
    out = cam.apply(np.repeat(img, 4, axis=0), None)
    assert out.dtype == np.uint8
    assert out[0].tolist() == [0, 64, 128, 255]  # 255 * level, rounded, clipped


def test_vignetting_profile():
    cam = CameraModel(vignetting=0.3, principal_point_px=(319.5, 239.5))
    v = cam.vignette(480, 640)
    assert v[240, 320] == pytest.approx(1.0, abs=1e-5)
    assert v[0, 0] == pytest.approx(0.7, abs=1e-6) and v[479, 639] == pytest.approx(0.7, abs=1e-6)
    # quadratic in the radius
    assert v[239, 319 + 200] == pytest.approx(1 - 0.3 * (199.5**2 + 0.5**2) / (319.5**2 + 239.5**2),
                                              abs=1e-5)


def test_noise_statistics_and_seeding():
    cam = CameraModel(exposure=1.0, read_noise=2.0, shot_noise=0.5, blur_px=0.0, vignetting=0.0)
    level = 100.0  # DN
    flat = np.full((200, 300), level / 255 * FULL_SCALE_RADIANCE)
    a = cam.apply(flat, np.random.default_rng(1)).astype(float)
    b = cam.apply(flat, np.random.default_rng(1))
    c = cam.apply(flat, np.random.default_rng(2))
    expected = np.sqrt(2.0**2 + 0.5**2 * level)  # read and shot noise add in quadrature
    assert a.std() == pytest.approx(np.sqrt(expected**2 + 1 / 12), rel=0.03)  # + rounding
    assert a.mean() == pytest.approx(level, abs=0.1)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_blur_keeps_centroids():
    centres = np.array([[40.3, 50.7], [110.55, 60.2]])
    img = disc_image(centres, 6.0, level=0.8 * FULL_SCALE_RADIANCE)
    cam = CameraModel(read_noise=0, shot_noise=0, blur_px=0.8, vignetting=0.0)
    out = cam.apply(img, None)
    got, _ = blob_centroids(out)
    matched, found = match_blobs(got, centres)
    assert found.all()
    assert np.max(np.abs(matched - centres)) < 0.03


def test_blob_centroids_on_known_discs():
    rng = np.random.default_rng(5)
    centres = np.array([[20, 20], [60, 25], [100, 30], [140, 40], [30, 90], [90, 85]]) + \
        rng.uniform(-0.5, 0.5, (6, 2))
    img = np.clip(np.rint(255 * disc_image(centres, 5.5, level=1.0)), 0, 255).astype(np.uint8)
    got, area = blob_centroids(img)
    matched, found = match_blobs(got, centres)
    assert found.all() and len(got) == 6
    assert np.max(np.linalg.norm(matched - centres, axis=1)) < 0.02
    assert np.all(np.abs(area - np.pi * 5.5**2) < 2 * np.pi * 5.5)
    # nothing to find in an empty image
    empty, _ = blob_centroids(np.zeros((50, 50), np.uint8), threshold=128)
    assert empty.shape == (0, 2)


def test_matching_is_one_to_one():
    expected = np.array([[10.0, 10.0], [12.0, 10.0], [np.nan, np.nan]])
    detected = np.array([[11.1, 10.0]])
    matched, found = match_blobs(detected, expected, max_dist_px=2.0)
    assert found.sum() == 1 and found[1] and np.isnan(matched[0]).all()


def test_frames_of_one_exposure_equal_apply_frame_by_frame():
    """frames() exposes once and digitises per frame: byte-identical to apply() called with the
    same generator, and the frames differ only by noise."""
    rad = np.random.default_rng(3).uniform(0, 2 * FULL_SCALE_RADIANCE, (40, 60)).astype(np.float32)
    cam = CameraModel(principal_point_px=(29.5, 19.5))
    got = cam.frames(rad, np.random.default_rng(9), 3)
    rng = np.random.default_rng(9)
    want = [cam.apply(rad, rng) for _ in range(3)]
    assert all(np.array_equal(g, w) for g, w in zip(got, want, strict=True))
    assert not np.array_equal(got[0], got[1])
    clean = cam.apply(rad, None)
    assert abs(float(np.mean(got[0].astype(float) - clean))) < 0.5  # zero-mean noise


def test_16bit_normal_draws_are_standard_normal():
    """The camera's Gaussian draws (inverse-CDF lookup of 16 random bits) against the normal
    distribution: unit variance, zero mean, symmetric, the quantiles of scipy's ndtri, and a
    Kolmogorov-Smirnov test on a million draws that rejects a 2 % error in the scale."""
    from scipy import stats
    from scipy.special import ndtri

    from tactip_sim.render.noise import normal_table, standard_normal_16bit

    t = normal_table().astype(np.float64)
    assert t.shape == (65536,) and np.all(np.diff(t) > 0)
    assert np.mean(t) == pytest.approx(0.0, abs=1e-12)
    assert np.mean(t * t) == pytest.approx(1.0, abs=1e-6)
    assert np.array_equal(t, -t[::-1])
    # the bin-centre quantiles, up to the variance rescale (1 - 3e-5 before it)
    k = np.array([100, 10_000, 32_768, 50_000, 65_000])
    assert np.allclose(t[k], ndtri((k + 0.5) / 65536), rtol=3e-5, atol=1e-6)
    x = standard_normal_16bit(np.random.default_rng(4), (1000, 1000)).ravel()
    assert x.dtype == np.float32
    assert stats.kstest(x, "norm").pvalue > 1e-3
    assert stats.kstest(x, stats.norm(scale=1.02).cdf).pvalue < 1e-3
    again = standard_normal_16bit(np.random.default_rng(4), (1000, 1000)).ravel()
    assert np.array_equal(x, again)


@pytest.mark.parametrize("given_sigma", [False, True])
def test_compiled_digitise_is_the_numpy_formula(given_sigma):
    """The one-pass compiled noise and quantisation (noise_kernels) against the NumPy formula
    it replaced, byte for byte: normal draws times the noise's sigma plus the exposed DN,
    rounded half to even, clipped to [0, 255]; DN from below 0 to past saturation, and (with a
    given sigma of 0 at those pixels) DN on the .5 rounding boundary."""
    from tactip_sim.render.noise import standard_normal_16bit

    cam = CameraModel(principal_point_px=(63.5, 47.5))
    rng = np.random.default_rng(11)
    rad = rng.uniform(-0.1, 1.4, (96, 128)).astype(np.float32) * FULL_SCALE_RADIANCE
    dn = cam.expose(rad)
    dn[0, :8] = np.float32([-3.5, -0.5, 0.5, 1.5, 2.5, 254.5, 255.5, 300.0])
    sigma = cam.noise_sigma(dn)
    if given_sigma:
        sigma[0, :8] = 0.0
    got = cam.digitise(dn, np.random.default_rng(5), sigma=sigma if given_sigma else None)
    want = standard_normal_16bit(np.random.default_rng(5), dn.shape)
    want *= sigma
    want += dn
    np.rint(want, out=want)
    np.clip(want, 0, 255, out=want)
    assert got.dtype == np.uint8 and np.array_equal(got, want.astype(np.uint8))
    # one frame: exposure and noise in one pass, the bytes of expose() then digitise()
    one = cam.frames(rad, np.random.default_rng(6), 1)
    assert len(one) == 1 and np.array_equal(one[0], cam.apply(rad, np.random.default_rng(6)))
    quiet = CameraModel(read_noise=0.0, shot_noise=0.0)
    assert np.array_equal(quiet.digitise(dn, np.random.default_rng(5)),
                          np.clip(np.rint(dn), 0, 255).astype(np.uint8))


@pytest.mark.parametrize("count", [1, 2, 7, 307_200])
def test_16bit_draws_are_the_generators_bytes(count):
    """random_bits_16 draws what np.frombuffer(rng.bytes(2 n), '<u2') does (Generator.bytes'
    own little-endian uint32 integers), also after other draws from the generator."""
    from tactip_sim.render.noise import random_bits_16

    a, b = np.random.default_rng(21), np.random.default_rng(21)
    a.integers(0, 2**31 - 1)
    b.integers(0, 2**31 - 1)
    want = np.frombuffer(a.bytes(2 * count), dtype="<u2")
    got = random_bits_16(b, count)
    assert got.dtype == np.dtype("<u2") and np.array_equal(got, want)
    assert a.integers(0, 1000, 5).tolist() == b.integers(0, 1000, 5).tolist()  # same state
