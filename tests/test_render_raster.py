"""The raster cap layer (``imaging.cap_layer = "raster"``): the coverage kernel against exact
areas and centroids, a cap's image against the lens formula, the layer against Mitsuba's on
the same markers, determinism, and the scene key's hash rule."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.render import Renderer
from tactip_sim.scene import scene_hash, scene_to_dict
from tactip_sim.scene._spec import SceneError


def disc_polygon(cx: float, cy: float, r: float, n: int = 720) -> np.ndarray:
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([cx + r * np.cos(phi), cy + r * np.sin(phi)])


def coverage(poly: np.ndarray, size: tuple[int, int] = (40, 30), sub_rows: int = 8
             ) -> np.ndarray:
    from tactip_sim.render.raster_kernels import polygon_coverage

    out = np.zeros((size[1], size[0]), np.float32)
    polygon_coverage(np.ascontiguousarray(poly, float), 0.0, 0.0, size[0], size[1], sub_rows,
                     out)
    return out


def moments(img: np.ndarray, x0: float = 0.0, y0: float = 0.0) -> tuple[float, np.ndarray]:
    v, u = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    s = float(img.sum())
    return s, np.array([(img * (u + x0)).sum() / s, (img * (v + y0)).sum() / s])


# ----------------------------------------------------------------------------- the kernel
@pytest.mark.parametrize(("cx", "cy", "r"), [(17.3, 12.8, 6.25), (20.0, 15.0, 2.2),
                                             (9.71, 20.04, 8.9)])
def test_disc_coverage_has_its_area_and_centre(cx, cy, r):
    img = coverage(disc_polygon(cx, cy, r))
    area, centre = moments(img)
    assert area == pytest.approx(np.pi * r * r, rel=2e-3)
    assert np.allclose(centre, [cx, cy], atol=5e-3)
    assert img.max() <= 1.0 + 1e-6 and img.min() >= 0.0


def test_axis_aligned_rectangle_is_exact_across_columns():
    # horizontal coverage is exact; the y edges fall on strip boundaries (multiples of 1/8)
    poly = np.array([[3.3, 4.5], [11.8, 4.5], [11.8, 9.5], [3.3, 9.5]])
    img = coverage(poly)
    assert img.sum() == pytest.approx(8.5 * 5.0, rel=1e-6)
    assert img[6, 3] == pytest.approx(0.2, abs=1e-6)  # column 3 spans [2.5, 3.5]: 0.2 inside
    assert img[6, 12] == pytest.approx(0.3, abs=1e-6)  # column 12 spans [11.5, 12.5]
    assert img[6, 11] == pytest.approx(1.0, abs=1e-6)
    assert img[6, 7] == pytest.approx(1.0, abs=1e-6)
    assert img[:4].sum() == 0 and img[10:].sum() == 0


def test_polygon_outside_the_window_draws_nothing():
    img = coverage(disc_polygon(-20.0, -20.0, 3.0))
    assert not img.any()


# ----------------------------------------------------------------------------- a cap's image
def test_cap_on_the_axis_images_as_the_lens_formula_says(scene):
    """An upright camera without refraction looking at a cap centred on its axis, facing it:
    an equidistant lens images the cap's rim (half-angle atan(R / D)) as a circle of radius
    f * atan(R / D) / pitch about the principal point."""
    s = ts.replace_in(scene, camera={"tilt_deg": 0.0, "shift_mm": 0.0},
                      imaging={"refraction": "none", "cap_layer": "raster"})
    r = Renderer(s)
    cam = r.camera
    centre = cam.centre_mm + np.array([0.0, 0.0, 18.0])  # 18 mm above the lens: in the gel
    radius = s.pins.marker_diameter_mm / 2
    glow, cover = r.raster("none").draw(centre[None], np.array([[0.0, 0.0, -1.0]]),
                                        np.array([1.0]))
    r_px = s.lens.focal_length_mm * np.arctan(radius / 18.0) / (s.camera.pixel_pitch_um / 1e3)
    x0, y0 = r.crop[:2]
    area, c = moments(cover, x0, y0)
    assert area == pytest.approx(np.pi * r_px**2, rel=3e-3)
    w, h = s.camera.resolution
    assert np.allclose(c, [(w - 1) / 2, (h - 1) / 2], atol=0.01)
    # no refraction: the sensor weight is 1, so the glow is the cap radiance times coverage
    assert np.allclose(glow, cover, atol=1e-6)


# ----------------------------------------------------------------------------- vs Mitsuba
@pytest.fixture(scope="module")
def both(scene, pad):
    raster = Renderer(ts.replace_in(scene, imaging={"cap_layer": "raster"}), pad)
    mitsuba = Renderer(scene, pad)
    # a smooth, seeded displacement of every cap (a pressed pad without the FEM)
    rng = np.random.default_rng(11)
    m = pad.markers_mm + np.array([0.15, -0.1, 0.3]) + rng.normal(0, 0.03, pad.markers_mm.shape)
    return raster, mitsuba, m, pad.pins.directions


def cap_sums(img: np.ndarray, background: np.ndarray, blobs: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per cap: the summed radiance above the background in a 25x25 window and its centroid."""
    tot, cen = [], []
    for x, y in blobs:
        x0, y0 = round(x) - 12, round(y) - 12
        w = np.clip(img[y0:y0 + 25, x0:x0 + 25] - background[y0:y0 + 25, x0:x0 + 25], 0, None)
        s, c = moments(w, x0, y0)
        tot.append(s)
        cen.append(c)
    return np.array(tot), np.array(cen)


def test_raster_caps_match_mitsuba_on_the_same_markers(both):
    raster, mitsuba, m, d = both
    ref = mitsuba.render_radiance(m, d, seed=5, spp=64)
    got = raster.render_radiance(m, d)
    _, vis, blobs = raster.ground_truth(m, d)
    assert vis.all()
    bg = raster.background("analytic")
    assert np.array_equal(bg, mitsuba.background("analytic"))  # disk cache = the same render
    t_ref, c_ref = cap_sums(ref, bg, blobs)
    t_got, c_got = cap_sums(got, bg, blobs)
    err = np.linalg.norm(c_got - c_ref, axis=1)
    # 64 spp Mitsuba scatters ~0.01 px about the exact coverage; 4 spp ~0.03 px
    assert err.max() <= 0.05 and np.mean(err) <= 0.015
    assert np.allclose(t_got / t_ref, 1.0, atol=0.01)
    # the raster changes the background only on and next to the pixels Mitsuba's caps hit
    # (a sliver of coverage can miss all 64 samples of an edge pixel)
    from scipy.ndimage import binary_dilation

    near = binary_dilation(ref != bg, iterations=1)
    assert np.array_equal(got[~near], bg[~near])


def test_raster_frames_find_every_marker_where_the_truth_says(both):
    from .test_render_frame import measured, rms

    raster, _, m, d = both
    frame = raster.render(m, d, rng=3)
    got, found = measured(frame)
    assert found.all()
    assert rms(got - frame.blobs_px) <= 0.1


def test_raster_is_deterministic_for_a_seed(both):
    raster, _, m, d = both
    a = raster.render(m, d, rng=7)
    b = raster.render(m, d, rng=7)
    c = raster.render(m, d, rng=8)
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)  # the sensor noise follows the seed
    assert np.array_equal(raster.render_radiance(m, d, seed=1),
                          raster.render_radiance(m, d, seed=2))  # no sampler: exact coverage



def test_interpolated_rims_are_the_projected_rims(both):
    """The cap outlines the raster draws (16 rim points projected, the other 32 their
    trigonometric interpolant) against all 48 rim points projected: within 1e-9 px for caps
    in the gel; a cap tilted so that its rim crosses the window's inner face (a kink in the
    refraction there) is projected point by point, to the bit."""
    from tactip_sim.optics.camera import cap_outline
    from tactip_sim.render.raster import N_EDGE

    raster, _, m, d = both
    d = d / np.linalg.norm(d, axis=1, keepdims=True)  # unit cap normals, as the renderer draws
    layer = raster.raster(raster.camera.refraction_mode(None))

    def projected(mm, dd):
        ring = cap_outline(mm, dd, layer.radius_mm, N_EDGE)
        return layer.camera.project(ring.reshape(-1, 3), refraction=layer.mode
                                    ).reshape(len(mm), N_EDGE, 2)

    got, want = layer.outlines(m, d), projected(m, d)
    assert np.abs(got - want).max() <= 1e-9
    tilted_m, tilted_d = m.copy(), d.copy()
    tilted_m[5, 2] = 0.1 * layer.radius_mm  # its rim dips below z = 0 when tilted 45 deg
    tilted_d[5] = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)
    got = layer.outlines(tilted_m, tilted_d)
    assert np.array_equal(got[5], projected(tilted_m[5:6], tilted_d[5:6])[0])
    assert np.abs(got - projected(tilted_m, tilted_d)).max() <= 1e-9


def test_truth_of_a_drawn_frame_is_the_projected_caps(both):
    """The ground truth of the frame the raster layer has just drawn takes its cap outlines
    from the drawing (its 16 projected rim points); it equals the 16-gon projected afresh
    (Camera.cap_images) to the bit, and markers that were not drawn are projected."""
    raster, mitsuba, m, d = both
    raster.render_radiance(m, d)
    mode = raster.camera.refraction_mode(None)
    # the drawing is reused (for the markers and unit directions the renderer drew)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    assert raster.raster(mode).last_outlines(m, unit) is not None
    got = raster.ground_truth(m, d)[2]
    want = mitsuba.ground_truth(m, d)[2]  # (Mitsuba draws no outlines: always projected)
    np.testing.assert_array_equal(got, want)
    moved = m + np.array([0.05, 0.0, 0.0])
    np.testing.assert_array_equal(raster.ground_truth(moved, d)[2],
                                  mitsuba.ground_truth(moved, d)[2])


def test_caps_over_the_background_are_the_layer_composited(both):
    """The one-pass composite (CapRaster.over) is draw()'s layer composited over the
    background, ``background (1 - cover) + layer`` over the crop in float32, to the bit (and is
    what render_radiance returns)."""
    from tactip_sim.render.scene import cap_radiance

    def composite(background, layer, cover):
        x0, y0, cw, ch = raster.crop
        out = background.copy()
        win = out[y0:y0 + ch, x0:x0 + cw]
        win *= np.float32(1.0) - cover
        win += layer
        return out

    raster, _, m, d = both
    mode = raster.camera.refraction_mode(None)
    background = raster.background(mode)
    assert background.dtype == np.float32
    glow = cap_radiance(raster.scene, raster.pad.leds_mm, m, d, raster.albedo.cap)
    layer, cover = raster.raster(mode).draw(m, d, glow)
    assert layer.dtype == np.float32 and cover.dtype == np.float32
    assert cover.max() > 0.5 and layer.max() > 0  # caps were drawn: the check has content
    want = composite(background, layer, cover)
    got = raster.raster(mode).over(background, m, d, glow)
    assert np.array_equal(got, want)
    assert np.array_equal(raster.render_radiance(m, d), want)
    colour = raster.raster(mode).over(np.stack([background, 2 * background], axis=-1), m, d,
                                      glow)
    assert np.array_equal(colour[..., 0], want)
    assert np.array_equal(colour[..., 1], composite(2 * background, layer, cover))

# ----------------------------------------------------------------------------- the scene key
def test_cap_layer_is_raster_by_default_and_mitsuba_one_key_away(scene):
    d = scene_to_dict(scene)
    assert "cap_layer" not in d["imaging"] and scene.imaging.cap_layer == "raster"
    mitsuba = ts.replace_in(scene, imaging={"cap_layer": "mitsuba"})
    assert scene_to_dict(mitsuba)["imaging"]["cap_layer"] == "mitsuba"
    assert scene_hash(mitsuba) != scene_hash(scene)
    assert scene_hash(ts.replace_in(mitsuba, imaging={"cap_layer": "raster"})) == \
        scene_hash(scene)


def test_bad_cap_layer_is_refused(scene):
    with pytest.raises(SceneError, match="cap_layer"):
        ts.replace_in(scene, imaging={"cap_layer": "opengl"})
    s = ts.replace_in(scene, imaging={"cap_layer": "raster"})
    with pytest.raises(ValueError, match="cap_layer='raster'"):
        Renderer(s, shading="lambert")
    with pytest.raises(ValueError, match="cap_layer='raster'"):
        Renderer(s, pins=True)


# ----------------------------------------------------------------------------- fidelity study
def test_raster_levels_are_in_the_fidelity_study_and_auto_applies_them(scene):
    from tactip_lab.sampling.fidelity_auto import scene_for_level
    from tactip_lab.studies.fidelity import study_levels

    levels = {lv.name: lv for lv in study_levels(scene)}
    one, fast = levels["raster caps"], levels["raster caps + 1 frame"]
    balanced = levels["balanced"].scene(scene)
    s1, s2 = one.scene(scene), fast.scene(scene)
    assert s1.imaging.cap_layer == "raster" and s2.imaging.cap_layer == "raster"
    assert s1.protocol.frames_per_sample == balanced.protocol.frames_per_sample
    assert s2.protocol.frames_per_sample == 1
    # the rest of the level is balanced: switching the layer back gives balanced's scene
    assert scene_hash(ts.replace_in(s1, imaging={"cap_layer": "mitsuba"})) == \
        scene_hash(balanced)
    # --fidelity auto applies a chosen level from its summary entry (full overrides)
    for lv, s in ((one, s1), (fast, s2)):
        assert scene_hash(scene_for_level(scene, {"settings": lv.overrides(scene)})) == \
            scene_hash(s)


def test_static_maps_from_the_disk_cache_are_the_computed_ones(both):
    from tactip_sim.render.raster import CapRaster

    raster, _, _, _ = both
    fresh = Renderer(raster.scene, raster.pad)  # a new renderer: its maps come from the cache
    got = fresh.raster("analytic")
    box, radius = raster.pad.protrusion_box_mm, raster.scene.pins.marker_diameter_mm / 2
    computed = CapRaster(fresh.camera, got.config, box, radius)  # its maps computed afresh
    assert np.array_equal(got.weight, computed.weight)
    assert np.array_equal(got.visible, computed.visible)
    assert 0.0 < got.visible.mean() < 1.0  # some crop pixels see the cavity, some do not
    with pytest.raises(ValueError, match="maps"):
        CapRaster(fresh.camera, got.config, box, radius,
                  maps=(got.weight[1:], got.visible))
