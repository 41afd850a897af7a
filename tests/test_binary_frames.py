"""Binarised frames (two grey levels): synthetic ones with known marker centres, a rim ring and
debris, touching pairs; and the real 128x128 processed frames of a 331-pin TacTip."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

import perception as pc
from perception.synthetic import render_markers

from .conftest import SHARED

C = np.array([64.0, 64.0])


def _binarised(centres, *, diameter=3.2, shape=(128, 128), ring=True, specks=()):
    """Anti-aliased discs thresholded at half level (the lab's processing binarises), a rim
    ring around them, and single-pixel specks at ``specks``."""
    frame = render_markers(centres, shape=shape, diameter_px=diameter, marker_level=1.0,
                           skin_level=0.0, exterior_level=0.0, sensor_radius_px=200.0).image
    out = np.where(frame >= 128, 255, 0).astype(np.uint8)
    if ring:
        cv2.circle(out, (64, 64), 60, 255, 3)
    for x, y in specks:
        out[y, x] = 255
    return out


def test_known_centres_through_a_ring_and_debris():
    rng = np.random.default_rng(1)
    centres = pc.hex_lattice(331, 5.0, C) + rng.uniform(-0.3, 0.3, (331, 2))  # as the real: r 50
    image = _binarised(centres, specks=[(64, 9), (10, 64), (118, 70)])
    det = pc.detect_markers_detailed(image, expected_count=331)
    assert det.reliable and det.count == 331, det.reason
    dist, _ = cKDTree(det.points).query(centres)
    # a 3 px disc binarised: its pixel centroid is within a third of a pixel of the centre
    assert np.median(dist) < 0.2 and dist.max() < 0.6
    # the ring and the three specks are rejected, and nothing near the ring is kept
    assert len(det.rejected_reasons) == 4
    assert np.linalg.norm(det.points - C, axis=1).max() < 56.0


def test_touching_pairs_are_split_into_their_two_markers():
    centres = pc.hex_lattice(61, 8.0, C)
    moved = centres.copy()
    moved[10] = centres[11] + np.array([-3.4, 0.0])  # marker 10 pressed against 11
    image = _binarised(moved, diameter=4.0, ring=False)
    det = pc.detect_markers_detailed(image, expected_count=61)
    assert det.count == 61
    d, _ = cKDTree(det.points).query(moved)
    assert d.max() < 1.0  # both members of the pair found near their centres


def _jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)


@pytest.mark.parametrize("convert", ["jpeg30", "jpeg50", "jpeg75", "jpeg95", "blur0.7"])
def test_binarised_frame_saved_as_jpeg_or_blurred_keeps_its_known_centres(convert):
    """JPEG's ringing or a blur turns a two-level frame into a grey one whose 1-3 px markers
    the grey-level path cannot read; cut back to two levels, it is read as binarised."""
    rng = np.random.default_rng(7)
    centres = pc.hex_lattice(331, 5.0, C) + rng.uniform(-0.3, 0.3, (331, 2))
    image = _binarised(centres)
    if convert.startswith("jpeg"):
        image = _jpeg(image, int(convert[4:]))
    else:
        image = cv2.GaussianBlur(image, (0, 0), float(convert[4:]))
    assert len(np.unique(image)) > 2  # no longer two-level
    det = pc.detect_markers_detailed(image, expected_count=331)
    assert det.reliable and det.count == 331, det.reason
    dist, _ = cKDTree(det.points).query(centres)
    assert np.median(dist) < 0.2 and dist.max() < 0.6


def test_dark_markers_on_a_bright_ground_are_the_same_markers():
    rng = np.random.default_rng(8)
    centres = pc.hex_lattice(331, 5.0, C) + rng.uniform(-0.3, 0.3, (331, 2))
    image = _binarised(centres, specks=[(64, 9)])
    bright = pc.detect_markers_detailed(image, expected_count=331)
    dark = pc.detect_markers_detailed(255 - image, expected_count=331)
    assert bright.reliable and dark.reliable, dark.reason
    np.testing.assert_array_equal(dark.points, bright.points)
    dist, _ = cKDTree(dark.points).query(centres)
    assert dist.max() < 0.6


def test_blank_and_single_level_frames_are_flagged_not_crashing():
    for image in (np.zeros((128, 128), np.uint8), np.full((128, 128), 255, np.uint8)):
        det = pc.detect_markers_detailed(image, expected_count=331)
        assert not det.reliable and det.count == 0


REAL128 = SHARED / "real" / "tactip331_tap128"


@pytest.mark.skipif(not REAL128.is_dir(), reason="../shared/real/tactip331_tap128 absent")
def test_real_128px_frames_find_99_percent_of_pins_in_every_frame():
    frames = sorted((REAL128 / "images").glob("*.png"))
    counts = np.array([pc.detect_markers_detailed(str(f), expected_count=331).count
                       for f in frames[::4]])
    assert len(counts) >= 200
    assert np.mean((counts >= 0.99 * 331) & (counts <= 1.01 * 331)) >= 0.95


@pytest.mark.skipif(not REAL128.is_dir(), reason="../shared/real/tactip331_tap128 absent")
def test_real_128px_frames_saved_as_jpeg_or_inverted_still_find_99_percent_of_pins():
    frames = sorted((REAL128 / "images").glob("*.png"))[::10]
    for convert in (lambda g: _jpeg(g, 75), lambda g: 255 - g):
        counts = np.array([pc.detect_markers_detailed(
            convert(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)), expected_count=331).count
            for f in frames])
        assert np.mean((counts >= 0.99 * 331) & (counts <= 1.01 * 331)) >= 0.95


@pytest.mark.skipif(not (SHARED / "real").is_dir(), reason="../shared/real absent")
def test_raw_and_binarised_full_resolution_real_frames():
    raws = sorted((SHARED / "real" / "tactip331_tap").glob("*.png"))
    raws.append(SHARED / "real" / "tactip331_raw" / "raw_tactile_image.png")
    for f in raws:
        grey = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        _, binary = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        for image in (str(f), binary):
            det = pc.detect_markers_detailed(image, expected_count=331)
            assert det.reliable and abs(det.count - 331) <= 4, (Path(f).name, det.reason)


def test_telling_the_count_never_makes_noise_reliable():
    """Blurred noise that happens to give about the expected number of blobs is still noise:
    the verdict with --expected-count is never weaker than without."""
    rng = np.random.default_rng(0)
    noise = cv2.GaussianBlur((rng.normal(0.5, 0.2, (480, 640)).clip(0, 1) * 255)
                             .astype(np.uint8), (0, 0), 4)
    free = pc.detect_markers_detailed(noise)
    told = pc.detect_markers_detailed(noise, expected_count=free.count)  # the count it found
    assert not free.reliable
    assert not told.reliable and "irregular" in told.reason


def test_detect_command_keeps_same_named_images_apart_and_writes_one_table(tmp_path, capsys):
    from tactip_sim.commands import main

    rng = np.random.default_rng(3)
    centres = pc.hex_lattice(331, 5.0, C) + rng.uniform(-0.3, 0.3, (331, 2))
    paths = []
    for sub, shift in (("a", 0.0), ("b", 1.0)):
        (tmp_path / sub).mkdir()
        paths.append(tmp_path / sub / "frame.png")
        cv2.imwrite(str(paths[-1]), _binarised(centres + shift))
    out, table = tmp_path / "out", tmp_path / "all.csv"
    assert main(["detect", *map(str, paths), "--expected-count", "331", "--out", str(out),
                 "--csv", str(table)]) == 0
    assert sorted(p.name for p in out.glob("*_markers.csv")) == ["frame_2_markers.csv",
                                                                 "frame_markers.csv"]
    rows = table.read_text().splitlines()
    assert rows[0].startswith("image,x_px,y_px") and len(rows) == 1 + 2 * 331
    first = np.loadtxt(out / "frame_markers.csv", delimiter=",", skiprows=1)
    second = np.loadtxt(out / "frame_2_markers.csv", delimiter=",", skiprows=1)
    assert np.allclose(np.sort(second[:, 0]) - np.sort(first[:, 0]), 1.0, atol=0.35)


def test_markers_pushed_against_the_rim_ring_are_kept():
    """A shear pushes the array against the rim ring: its outer markers come within a marker
    diameter and a half of the ring, where components were all taken for ring fragments.
    They sit in the array's lattice (two markers within 1.5 spacings, a marker's size) and are
    kept, each at its centre."""
    centres = pc.hex_lattice(331, 5.0, (66.0, 64.0))  # array radius ~48 px, 2 px right
    image = _binarised(centres, ring=False)
    cv2.circle(image, (64, 64), 55, 255, 3)  # the ring's inner edge ~53.5 px: outer markers
    # on the right come to ~3.5 px (< 1.5 diameters, 4.8 px) of it
    assert cv2.connectedComponents(image, connectivity=8)[0] == 1 + 331 + 1  # none merged
    near_ring = np.hypot(*(centres - 64.0).T) > 53.5 - 1.5 * 3.2
    assert near_ring.sum() >= 6  # the case is exercised
    det = pc.detect_markers_detailed(image, expected_count=331)
    d, _ = cKDTree(det.points).query(centres)
    assert det.count == 331 and d.max() < 0.6, det.reason
