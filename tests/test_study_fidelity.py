"""The fidelity study: Pareto front, the auto choice and a quick study on a small scene.

The quick study uses a cheaper stand-in reference (``balanced`` with Lambert-shaded caps at
16 spp) instead of the neo-Hookean, path-traced ``reference`` preset, which costs minutes per
pose; the logic under test (errors against a reference on shared seeds, the choice, its
check on fresh poses) is the same.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import tactip_sim as ts
from tactip_lab.sampling.fidelity_auto import choose_level
from tactip_lab.studies.fidelity import (
    Level,
    compare_levels,
    pareto_front,
    run_fidelity_study,
    study_levels,
)
from tactip_sim.scene import apply_preset
from tactip_sim.scene.schema import SECTIONS

from .conftest import ROOT

SMALL = {"camera": {"resolution": [320, 240], "pixel_pitch_um": 16.8}}
STAND_IN = Level("reference (stand-in)", "preset",
                 {"imaging": {"spp": 16, "shading": "lambert"}}, base="balanced")
LEVELS = ["fast", "balanced", "1 spp", "embedded pins"]
TOLERANCE_PX = 0.5


def test_pareto_front_known_answer():
    t = [1.0, 2.0, 3.0, 0.5, 2.0, np.nan]
    e = [0.5, 0.2, 0.3, 1.0, 0.2, 0.0]
    # 3.0/0.3 is beaten by 2.0/0.2; the two 2.0/0.2 tie and both stay; NaN is never on it
    assert pareto_front(t, e).tolist() == [True, True, False, True, True, False]


def _summary(*levels):
    return {"levels": [dict(name=n, sample_s=t, marker_px_p95=px, marker_mm_max=0.0,
                            cop_px_max=px, r2=r2, error="", settings={})
                       for n, t, px, r2 in levels]}


def test_choose_level_takes_the_cheapest_that_meets_every_tolerance():
    s = _summary(("ref", 10.0, 0.0, 0.99), ("a", 0.1, 0.8, 0.97), ("b", 0.5, 0.15, 0.98),
                 ("c", 1.0, 0.05, 0.90))
    assert choose_level(s, max_marker_error_px=0.2)["name"] == "b"
    assert choose_level(s, max_marker_error_px=1.0)["name"] == "a"
    assert choose_level(s, max_marker_error_px=0.2, min_r2=0.985)["name"] == "ref"
    assert choose_level(s, min_r2=0.95)["name"] == "a"
    with pytest.raises(ValueError, match="no level of the fidelity study meets"):
        choose_level(s, min_r2=0.999)
    with pytest.raises(ValueError, match="needs a tolerance"):
        choose_level(s)


def test_levels_cover_every_stage(scene):
    levels = study_levels(scene)
    assert {"fast", "balanced", "reference"} <= {lv.name for lv in levels}
    assert {lv.stage for lv in levels} == {"preset", "physics", "render", "perception"}
    balanced = apply_preset(scene, "balanced")
    for lv in levels:
        s = lv.scene(scene)
        if lv.base != "balanced" or not lv.settings:
            continue
        # a one-knob variant differs from `balanced` in its knob's section(s) and nowhere else
        changed = {sec for sec in SECTIONS if getattr(s, sec) != getattr(balanced, sec)}
        assert changed == set(lv.settings), lv.name
    by = {lv.name: lv.scene(scene) for lv in levels}
    assert by["1 spp"].imaging.spp == 1 and by["16 spp"].imaging.spp == 16
    w, h = scene.camera.resolution
    assert tuple(by["half resolution"].camera.resolution) == (w // 2, h // 2)
    assert by["P1 elements"].fidelity.element_order == 1
    assert by["8 frames"].protocol.frames_per_sample == 8


@pytest.fixture(scope="module")
def small(scene):
    return ts.replace_in(scene, **SMALL)


@pytest.fixture(scope="module")
def study(small, tmp_path_factory):
    out = tmp_path_factory.mktemp("fidelity")
    summary = run_fidelity_study(small, out, quick=True, levels=LEVELS, reference=STAND_IN,
                                 progress=False, log=lambda s: None)
    return out, summary


def test_study_writes_its_report_chart_and_tables(study):
    out, summary = study
    assert (out / "front.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "](front.png)" in (out / "report.md").read_text()
    on_disk = json.loads((out / "summary.json").read_text())
    names = [lv["name"] for lv in on_disk["levels"]]
    assert names[0] == STAND_IN.name and set(LEVELS) <= set(names)
    assert len((out / "levels.csv").read_text().splitlines()) == len(names) + 1


def test_study_errors_come_from_the_right_stages(study):
    _, summary = study
    by = {lv["name"]: lv for lv in summary["levels"]}
    for lv in by.values():
        assert not lv["error"], lv
        assert lv["sample_s"] > 0 and lv["physics_s"] >= 0
    # a render knob shares the reference's physics: identical FEM markers
    assert by["1 spp"]["marker_mm_max"] == 0.0
    # a physics knob moves the markers, and the perceived markers and CoP with them
    assert by["embedded pins"]["marker_mm_max"] > 1e-3
    assert by["fast"]["marker_mm_max"] > 1e-3
    for name in LEVELS:
        assert 0 < by[name]["marker_px_p95"] <= by[name]["marker_px_max"]
        assert np.isfinite(by[name]["cop_px_max"])
        if by[name]["r2"] is not None:
            assert -1.0 < by[name]["r2"] <= 1.0


def test_auto_choice_meets_its_tolerance_on_fresh_poses(study, small):
    _, summary = study
    choice = choose_level(summary, max_marker_error_px=TOLERANCE_PX)
    assert choice["name"] != STAND_IN.name
    assert choice["marker_px_p95"] <= TOLERANCE_PX
    level = next(lv for lv in study_levels(small) if lv.name == choice["name"])
    p = small.protocol
    rng = np.random.default_rng(12345)  # poses the study never saw
    fresh = np.stack([rng.uniform(*p.roll_range_deg, 2), rng.uniform(*p.pitch_range_deg, 2),
                      np.full(2, p.training_depth_mm)], axis=1)
    errors = compare_levels(small, level, STAND_IN, fresh, frames_cap=2)
    assert errors["marker_px_p95"] <= TOLERANCE_PX, (choice["name"], errors)


def test_sweep_with_fidelity_auto_uses_and_records_the_choice(study, scene_path, tmp_path,
                                                             capsys):
    from tactip_sim.commands import main

    out, summary = study
    choice = choose_level(summary, max_marker_error_px=TOLERANCE_PX)
    ds = tmp_path / "ds"
    argv = ["sweep", str(scene_path), "--out", str(ds), "--random", "2", "--frames", "1",
            "--nominal", "--no-progress", "--fidelity", "auto", "--study", str(out),
            "--max-marker-error-px", str(TOLERANCE_PX)]
    for sec, kv in SMALL.items():
        argv += [a for k, v in kv.items() for a in ("--set", f"{sec}.{k}={json.dumps(v)}")]
    assert main(argv) == 0
    manifest = json.loads((ds / "manifest.json").read_text())
    from tactip_sim.scene import scene_from_dict

    recorded = scene_from_dict(manifest["scene"])  # (the dict omits some keys at default)
    for sec, kv in choice["settings"].items():
        for k, v in kv.items():
            assert getattr(getattr(recorded, sec), k) == v, (sec, k)
    # a study of another scene is refused
    bad = argv[:argv.index("--set")] + ["--set", "imaging.spp=5"]
    assert main(bad) == 1
    assert "measured on a different scene" in capsys.readouterr().err


def test_a_study_knows_its_scene_at_its_base_level_whatever_the_defaults(scene):
    """The bundled study (measured when the defaults were the paper level) is the default
    scene's study today: both are compared at the study's base level, where the fidelity
    keys every level sets are set; a design change still makes it another scene."""
    from tactip_lab.sampling.fidelity_auto import study_hash

    bundled = json.loads((ROOT / "docs" / "fidelity" / "summary.json").read_text())
    assert study_hash(scene) == bundled["scene_hash"]
    paper = ts.replace_in(scene, imaging={"cap_layer": "mitsuba"},
                          protocol={"frame_average": "features"})
    assert study_hash(paper) == study_hash(scene)
    assert study_hash(ts.replace_in(scene, imaging={"spp": 9})) == study_hash(scene)
    assert study_hash(ts.replace_in(scene, gel={"youngs_modulus_kpa": 31.0})) != \
        study_hash(scene)
