"""Rendered frames against the analytic ground truth (Mitsuba, llvm_ad_rgb)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Camera, Criteria, Layers, resolvable, visibility
from tactip_sim.render import Frame, Renderer, blob_centroids, match_blobs
from tactip_sim.render.scene import Albedo

from .test_optics_refraction import fermat_air_direction, mount_by_hand, project_by_hand


@pytest.fixture(scope="module")
def renderer(scene, pad):
    return Renderer(scene, pad)


def measured(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Blob centroids (threshold + connected components, intensity-weighted) assigned to the
    markers; (97, 2) with NaN where none was found, and the found mask."""
    cent, _ = blob_centroids(frame.image)
    return match_blobs(cent, frame.blobs_px)


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(a**2, axis=1))))


def test_rest_pose_centroids_match_the_analytic_projection(renderer, scene, pad):
    frame = renderer.render(rng=0)
    assert frame.image.dtype == np.uint8 and frame.image.shape == (480, 640)
    assert frame.visible.all()
    assert np.allclose(frame.markers_px, Camera.from_scene(scene).project(pad.markers_mm))
    got, found = measured(frame)
    assert found.all()
    # against the centroid of each cap's exactly projected outline
    assert rms(got - frame.blobs_px) <= 0.1
    # against the image of each cap's centre: larger by the physical blob offset (~0.12 px)
    offset = rms(frame.blobs_px - frame.markers_px)
    assert rms(got - frame.markers_px) <= np.hypot(0.1, offset) + 0.02


def displaced(pad, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rest markers moved as a press might move them (mm): a smooth bump of the skin around a
    contact point (markers pushed towards the window and outwards), a common shear, and a small
    seeded jitter of each marker; pins tilted with the bump's slope."""
    rng = np.random.default_rng(100 + k)
    m0 = pad.markers_mm
    centre = np.array([[-6.0, 2.0], [0.0, 0.0], [7.0, -4.0]])[k]
    r = m0[:, :2] - centre
    bump = np.exp(-np.sum(r**2, axis=1) / (2 * 6.0**2))  # 6 mm wide
    m = m0.copy()
    m[:, 2] -= 1.0 * bump  # pressed towards the window
    m[:, :2] += 0.08 * r * bump[:, None]  # spread outwards
    m[:, :2] += [0.3 * (k - 1), -0.2 * k]  # shear
    m += rng.normal(0.0, 0.03, m.shape)
    d = pad.pins.directions.copy()
    d[:, :2] += 0.1 * r * bump[:, None] / 6.0
    return m, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_displaced_markers_are_tracked(renderer, scene, pad, k, monkeypatch):
    renderer.render(rng=0)  # the scenes of this setting exist
    loads = []
    real_load = renderer.mi.load_dict

    def counted_load(*args, **kwargs):
        loads.append(args)
        return real_load(*args, **kwargs)

    monkeypatch.setattr(renderer.mi, "load_dict", counted_load)
    m, d = displaced(pad, k)
    frame = renderer.render(m, d, rng=k)
    # markers moved through mi.traverse: no Mitsuba scene (nor any of its parts) was rebuilt
    assert loads == []
    camera = Camera.from_scene(scene)
    assert np.allclose(frame.markers_px, camera.project(m))
    vis = visibility(camera, pad, m, d)
    _, diam, outline = camera.cap_images(m, d, scene.pins.marker_diameter_mm / 2)
    ok, _ = resolvable(camera, vis, diam, outline, Criteria.from_scene(scene))
    assert ok.sum() >= 85
    got, found = measured(frame)
    assert found[ok].all()
    assert rms((got - frame.blobs_px)[ok]) <= 0.1


def test_same_seed_same_bytes(renderer):
    a = renderer.render(rng=7)
    b = renderer.render(rng=7)
    c = renderer.render(rng=8)
    assert a.image.tobytes() == b.image.tobytes()
    assert a.image.tobytes() != c.image.tobytes()
    # the noise differs but the scene does not: same markers found at the same places
    assert rms(measured(a)[0] - measured(c)[0]) < 0.1
    g = np.random.default_rng(7)
    assert renderer.render(rng=g).image.tobytes() == a.image.tobytes()


def test_turning_refraction_off_moves_markers_as_snell_says(renderer, scene, pad):
    on = renderer.render(rng=1)
    off = renderer.render(rng=1, refraction="none")
    got_on, found_on = measured(on)
    got_off, found_off = measured(off)
    assert found_on.all() and found_off.all()
    shift = got_on - got_off
    assert rms(shift - (on.blobs_px - off.blobs_px)) <= 0.1
    assert np.mean(np.linalg.norm(shift, axis=1)) > 5.0
    # the marker that moves most, predicted from Fermat's principle and the lens formula
    i = int(np.argmax(np.linalg.norm(shift, axis=1)))
    c, p = mount_by_hand(scene)[0], pad.markers_mm[i]
    expected = (project_by_hand(scene, fermat_air_direction(c, p, Layers.from_scene(scene)))
                - project_by_hand(scene, (p - c) / np.linalg.norm(p - c)))
    assert np.linalg.norm(shift[i] - expected) <= 0.2


def test_analytic_refraction_matches_path_traced_dielectrics(scene, pad):
    # black rim and body: no ghost reflections of the lit body in the window (the path tracer
    # would add them as noise); only the geometry of refraction is compared
    r = Renderer(scene, pad, albedo=Albedo(rim=0.0, body=0.0))
    analytic = r.render(rng=2)
    path = r.render(rng=2, refraction="path", spp=8)
    assert path.meta["refraction"] == "path"
    a, fa = measured(analytic)
    b, fb = measured(path)
    assert fa.all() and fb.all()
    assert rms(a - b) <= 0.2
    assert np.max(np.linalg.norm(a - b, axis=1)) <= 0.4


def test_lambert_caps_are_biased_towards_the_light(scene, pad):
    mitsuba = ts.replace_in(scene, imaging={"cap_layer": "mitsuba"})  # lambert: Mitsuba's caps
    frame = Renderer(mitsuba, pad, shading="lambert").render(rng=3)
    got, found = measured(frame)
    assert found.all()
    err = rms(got - frame.blobs_px)
    assert 0.05 < err <= 0.25  # shading gradients across the caps pull the centroids


def test_frame_is_saved_with_its_truth(renderer, tmp_path):
    import json

    import cv2

    frame = renderer.render(rng=4)
    paths = frame.save(tmp_path / "f.png")
    img = cv2.imread(str(paths["png"]), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(img, frame.image)
    truth = json.loads(paths["json"].read_text())
    assert np.allclose(truth["markers_px"], frame.markers_px, atol=1e-4)
    assert truth["visible"] == frame.visible.tolist()
    rows = paths["csv"].read_text().splitlines()
    assert len(rows) == 98 and rows[0].startswith("marker,x_px,y_px")


def test_bad_marker_arrays_are_rejected(renderer):
    with pytest.raises(ValueError, match=r"\(97, 3\)"):
        renderer.render(np.zeros((3, 3)))


def test_missing_llvm_gives_a_clear_error(tmp_path, scene_path):
    code = (
        "import tactip_sim as ts\n"
        "from tactip_sim.render import Renderer\n"
        f"r = Renderer(ts.load_scene({str(scene_path)!r}))\n"
        "try:\n    r.render()\nexcept ts.LLVMError as e:\n    print('LLVMError', e)\n"
    )
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(tmp_path / "libLLVM-missing.so"),
               TACTIP_CACHE_DIR=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=False, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "LLVMError" in res.stdout and "libllvm19" in res.stdout


@pytest.mark.parametrize(("model", "extra"), [
    ("equisolid", {}),
    ("stereographic", {}),
    ("rectilinear", {"fov_deg": 150.0}),
    ("kannala_brandt", {"kb_coeffs": [0.03, -0.01, 0.002, 0.0]}),
])
def test_every_lens_model_renders_where_it_projects(scene, model, extra):
    sc = ts.replace_in(scene, lens={"model": model, **extra})
    frame = Renderer(sc).render(rng=5)
    got, found = measured(frame)
    assert found.all()
    assert rms(got - frame.blobs_px) <= 0.1


def test_colour_and_ambient(scene):
    sc = ts.replace_in(scene, imaging={"colour": True}, lighting={"ambient": 0.05})
    frame = Renderer(sc).render(rng=6)
    assert frame.image.shape == (480, 640, 3)
    got, found = measured(frame)
    assert found.all() and rms(got - frame.blobs_px) <= 0.1
    # grey materials: the three channels agree up to the independent noise
    diff = frame.image.astype(int)[..., 0] - frame.image.astype(int)[..., 2]
    assert abs(diff.mean()) < 0.5
