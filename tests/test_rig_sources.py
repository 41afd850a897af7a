"""The rig's second set of sources, each against its own mechanics: the Prony series against
the hereditary integral and the Maxwell branches' equations, the motion-blur kernel's moments,
JPEG's error against quality, the scene-level sources, and the sweep path they take."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

import tactip_sim as ts
from tactip_lab.rig.prony import Prony
from tactip_lab.rig.sources import (
    SOURCES,
    RigModel,
    blur_kernel,
    check_sources,
    jpeg_roundtrip,
    load_rig,
    motion_blur,
)
from tactip_lab.sampling.chain import Chain, set_tag
from tactip_lab.sampling.poses import PoseSet, make_tip
from tactip_lab.sampling.sweep import SweepSpec, rig_sample, run_sweep

from .conftest import ROOT

TWO = Prony((0.3, 0.2), (0.7, 4.0))  # chosen for the tests, not the rig's values


def test_relaxation_is_the_maxwell_branches_stress_under_a_held_strain():
    # second method: integrate each branch's viscous strain dq/dt = (e - q)/tau under a unit
    # step strain and sum the stresses g_inf e + sum g_i (e - q_i)
    g, tau = np.array(TWO.g), np.array(TWO.tau_s)
    sol = solve_ivp(lambda t, q: (1.0 - q) / tau, (0, 10), np.zeros(2), rtol=1e-10, atol=1e-12,
                    dense_output=True)
    t = np.array([0.0, 0.1, 0.7, 2.0, 4.0, 9.5])
    stress = TWO.g_inf + (g[:, None] * (1.0 - sol.sol(t))).sum(axis=0)
    np.testing.assert_allclose(TWO.relaxation(t), stress, rtol=1e-7)
    assert TWO.relaxation(0.0) == pytest.approx(1.0)
    assert TWO.relaxation(1e4) == pytest.approx(0.5)


def test_capture_mean_against_quadrature():
    for start, length in ((0.5, 3.0), (0.0, 0.2), (10.0, 30.0)):
        expected = quad(lambda t: float(TWO.relaxation(t)), start, start + length)[0] / length
        assert TWO.mean_relaxation(start, length) == pytest.approx(expected, rel=1e-9)
    # the capture sees the modulus of a durometer read at 1 s scaled by the mean over 3 s
    # starting 0.5 s in: softer (later) than 1 s on average here
    r = TWO.capture_ratio(delay_s=0.5, capture_s=3.0, reference_s=1.0)
    assert r == pytest.approx(TWO.mean_relaxation(0.5, 3.0) / float(TWO.relaxation(1.0)))
    assert r < 1


def test_residual_of_one_branch_is_the_standard_linear_solids():
    # analytic: a standard linear solid released after a hold T recovers the strain
    # g (1 - exp(-T/tau)) exp(-(1 - g) s / tau)  (derived by hand from the SLS equations)
    sls = Prony((0.4,), (1.5,))
    hold = 3.0
    s = np.array([0.0, 0.5, 2.0, 6.0])
    expected = 0.4 * (1 - np.exp(-hold / 1.5)) * np.exp(-(1 - 0.4) * s / 1.5)
    np.testing.assert_allclose(sls.residual_after_release(hold, s), expected, rtol=1e-10)


def test_residual_of_two_branches_against_the_hereditary_integral():
    # second method: Boltzmann superposition with the closed-form G(t), stepping the strain
    # after release so that the stress stays zero (a Volterra equation solved step by step)
    hold, dt, n = 3.5, 0.002, 2500
    times = [0.0, hold]
    jumps = [1.0, None]
    t_after = hold + dt * np.arange(n)
    # the instantaneous recovery at release: the stress the held strain still carried
    jumps[1] = -float(TWO.relaxation(hold))
    steps_t = np.array(times)
    steps = np.array(jumps, dtype=float)
    strain = [1.0 + jumps[1]]
    incr = []
    for k in range(1, n):
        t = t_after[k]
        hist = (steps * TWO.relaxation(t - steps_t)).sum()
        if incr:
            hist += (np.array(incr) * TWO.relaxation(t - t_after[1:k] + dt / 2)).sum()
        d = -hist  # G(0) = 1
        incr.append(d)
        strain.append(strain[-1] + d)
    strain = np.array(strain)
    s = np.array([0.0, 0.5, 1.0, 3.0])
    idx = np.round(s / dt).astype(int)
    np.testing.assert_allclose(TWO.residual_after_release(hold, s), strain[idx], atol=3e-3)
    # the instantaneous recovery is the relaxed stress at release; a solid recovers fully
    assert TWO.residual_after_release(hold, 0.0) == pytest.approx(1 - TWO.relaxation(hold))
    assert TWO.residual_after_release(hold, 500.0) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(("kwargs", "pattern"), [
    ({"skin_prony_g": (-0.1,), "skin_prony_tau_s": (1.0,)},
     r"rig\.skin_prony_g\[0\]=-0\.1 is negative"),
    ({"gel_prony_g": (0.1,), "gel_prony_tau_s": (0.0,)},
     r"rig\.gel_prony_tau_s\[0\]=0 must be > 0"),
    ({"skin_prony_g": (0.6, 0.5), "skin_prony_tau_s": (1.0, 2.0)}, r"rig\.skin_prony_g sums"),
    ({"skin_prony_g": (0.1,), "skin_prony_tau_s": (1.0, 2.0)}, r"one relaxation time per term"),
    ({"relaxation": True}, r"rig\.relaxation is on but rig\.skin_prony_g is empty"),
    ({"jpeg_quality": 50.5}, r"rig\.jpeg_quality=50\.5 must be a whole number"),
    ({"motion_blur_px": -2.0}, r"rig\.motion_blur_px=-2\.0 is out of range"),
    ({"exposure_trend": -0.1}, r"rig\.exposure_trend=-0\.1 is out of range"),
])
def test_bad_magnitudes_name_the_key(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        RigModel(**kwargs)


def test_unknown_sources_and_presets_are_refused():
    with pytest.raises(ValueError, match=r"unknown rig source 'lens'.*robot"):
        check_sources(["robot", "lens"])
    with pytest.raises(ValueError, match=r"--rig 'perfect' is neither a rig file nor a preset.*"
                                         r"realistic"):
        load_rig("perfect")


def test_realistic_preset_cites_every_magnitude_and_old_records_stay():
    rig = load_rig("realistic")
    assert rig == RigModel.from_file(ROOT / "rigs" / "realistic.toml")
    cited = dict(rig.sources)
    for keys in SOURCES.values():
        for key in keys:
            assert len(cited.get(key, "")) > 20, key
    assert rig.relaxation and rig.hysteresis and rig.jpeg_quality > 0
    # records made before the second set of sources keep their keys (dataset identities)
    assert set(RigModel().record()) == {"pose_depth_sd_mm", "pose_angle_sd_deg",
                                        "zero_step_mm", "exposure_drift_sd", "sources"}
    old = RigModel.from_file(ROOT / "rigs" / "pestell_ur5.toml").record()
    assert set(old) == set(RigModel().record())
    # only(): the named sources keep their values, the rest are off (nominal tips included)
    h = rig.only(["hysteresis"])
    assert h.hysteresis and not h.relaxation and h.jpeg_quality == 0
    assert h.manufacturing_scale == 0 and h.zero_step_mm == 0 and h.skin == rig.skin
    assert rig.only([]).ideal


def test_scene_level_sources(scene):
    assert RigModel().apply_to_scene(scene) is scene  # the default rig: the scene unchanged
    rig = RigModel(relaxation=True, skin_prony_g=(0.3,), skin_prony_tau_s=(2.0,),
                   gel_prony_g=(0.1,), gel_prony_tau_s=(5.0,))
    relaxed = rig.apply_to_scene(scene)
    skin_r = rig.skin.mean_relaxation(0.5, 3.0) / float(rig.skin.relaxation(1.0))
    gel_r = rig.gel.mean_relaxation(0.5, 3.0) / float(rig.gel.relaxation(1.0))
    assert relaxed.skin.youngs_modulus_kpa == pytest.approx(scene.skin.youngs_modulus_kpa
                                                            * skin_r)
    assert relaxed.gel.youngs_modulus_kpa == pytest.approx(scene.gel.youngs_modulus_kpa * gel_r)
    nominal = RigModel(manufacturing_scale=0.0).apply_to_scene(scene)
    tip = make_tip(nominal, "B")
    assert not tip.pin_offsets_mm.any() and all(v == 0 for v in tip.draws.values())
    doubled = make_tip(RigModel(manufacturing_scale=2.0).apply_to_scene(scene), "B")
    once = make_tip(scene, "B")
    # the same seeded draws, twice as large (the +-3 sd clip scales with them)
    np.testing.assert_allclose(doubled.pin_offsets_mm, 2 * once.pin_offsets_mm, atol=1e-12)


def test_blur_kernel_is_a_segment_of_the_given_length():
    for length, angle in ((6.0, 0.0), (9.0, 0.6)):
        k = blur_kernel(length, angle)
        assert k.sum() == pytest.approx(1.0)
        c = k.shape[0] // 2
        yy, xx = np.mgrid[:k.shape[0], :k.shape[1]] - c
        along = xx * np.cos(angle) + yy * np.sin(angle)
        across = -xx * np.sin(angle) + yy * np.cos(angle)
        # a uniform segment of length L has variance L^2/12 along it (+ 1/6 px^2 from the
        # bilinear splat of each point over two pixels, at most); none across but the splat
        assert (k * along**2).sum() == pytest.approx(length**2 / 12, abs=0.35)
        assert (k * across**2).sum() < 0.35
    dot = np.zeros((41, 41))
    dot[20, 20] = 1.0
    line = motion_blur(dot, 10.0, 0.0)
    assert line.sum() == pytest.approx(1.0) and np.count_nonzero(line[20] > 1e-3) >= 10
    assert np.abs(line[:18]).max() < 1e-12  # nothing off the horizontal line


def test_jpeg_error_falls_with_quality(scene):
    rng = np.random.default_rng(3)
    img = np.clip(rng.normal(128, 30, (120, 160)), 0, 255).astype(np.uint8)
    errs = [np.sqrt(np.mean((jpeg_roundtrip(img, q).astype(float) - img) ** 2))
            for q in (10, 50, 75, 95)]
    assert all(a > b for a, b in zip(errs, errs[1:], strict=False)) and errs[-1] > 0


def _small(scene):
    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2})


def test_the_rig_sample_path_with_its_sources_at_zero_is_the_chains(scene):
    small = _small(scene)
    spec = SweepSpec(small, "A", PoseSet("p", np.array([[4.0, -2.0, 1.0]])), frames=2,
                     nominal=True)
    chain = Chain.for_tip(small, "A", nominal=True, frames=2)
    a = chain.sample((4.0, -2.0, 1.0), set_tag("p"), 0)
    b = rig_sample(spec, chain, 0, (4.0, -2.0, 1.0), 1.0, np.random.default_rng(0))
    for x, y in zip(a.rendered.images, b.rendered.images, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.perceived.cop_growth, b.perceived.cop_growth)


def test_a_sweep_with_the_new_sources_is_seeded_and_lags_by_hysteresis(scene, tmp_path):
    small = _small(scene)
    poses = np.array([[8.0, -2.0, 1.0], [-8.0, -6.0, 1.0]])
    prony = {"skin_prony_g": (0.4,), "skin_prony_tau_s": (30.0,)}
    hyst = RigModel(hysteresis=True, **prony)
    h = hyst.hysteresis_fraction()
    assert 0.02 < h < 0.4
    runs = {}
    for name, rig in (("ideal", RigModel()), ("hyst", hyst),
                      ("cam", RigModel(jpeg_quality=60, motion_blur_px=4.0, exposure_trend=0.1)),
                      ("cam2", RigModel(jpeg_quality=60, motion_blur_px=4.0,
                                        exposure_trend=0.1))):
        spec = SweepSpec(small, "A", PoseSet("p", poses), frames=1, nominal=True, rig=rig)
        runs[name] = run_sweep(spec, tmp_path / name, progress=False).dataset.records()
    ideal, hy = runs["ideal"], runs["hyst"]
    # the first pose has no previous one; the second's markers lag towards the first's
    np.testing.assert_array_equal(ideal[0].markers_mm, hy[0].markers_mm)
    np.testing.assert_allclose(hy[1].markers_mm,
                               (1 - h) * ideal[1].markers_mm + h * ideal[0].markers_mm,
                               atol=1e-12)
    a, b = runs["cam"], runs["cam2"]  # seeded: the same rig gives the same features
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.cop_growth_px, y.cop_growth_px)
    assert not np.array_equal(a[1].cop_growth_px, ideal[1].cop_growth_px)
