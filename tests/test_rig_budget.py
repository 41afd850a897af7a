"""The rig study's bookkeeping (calibration/studies/rig_budget.py): its configurations, the
ranking of sources by the R² they cost, the report and chart. The protocol runs themselves
are ``tactip calibrate``'s (tested there); the measured budget is in docs/rig.md."""

import pytest

from calibration.fit import FEATURES
from calibration.rig import SOURCES, load_rig
from calibration.studies.rig_budget import chart, configs, ranking, report


def test_configurations_switch_one_source_on_at_a_time():
    rig = load_rig("realistic")
    cfgs = configs(rig, list(SOURCES))
    # motion blur is 0 in the realistic rig: alone it would be the ideal rig, so left out
    assert list(cfgs) == ["ideal", "robot", "zero", "exposure", "relaxation", "hysteresis",
                          "compression", "manufacturing", "load_path", "all"]
    ideal = cfgs["ideal"]
    assert ideal.ideal and ideal.modulus_ratios() == (1.0, 1.0)
    assert ideal.manufacturing_scale == 0.0  # nominal tips
    assert cfgs["all"] is rig
    assert cfgs["compression"].jpeg_quality == 75 and cfgs["compression"].zero_step_mm == 0
    assert cfgs["zero"].zero_step_mm == 0.1 and cfgs["zero"].jpeg_quality == 0
    assert cfgs["relaxation"].modulus_ratios()[0] < 1 and not cfgs["relaxation"].hysteresis
    assert cfgs["manufacturing"].manufacturing_scale == 1.0
    assert cfgs["robot"].pose_depth_sd_mm == 0.033 and cfgs["robot"].exposure_drift_sd == 0
    with pytest.raises(ValueError, match="unknown rig source 'wind'"):
        configs(rig, ["wind"])
    path = cfgs["load_path"]
    assert path.friction_path and path.friction_coefficient == 0.5 and path.zero_step_mm == 0
    assert not cfgs["zero"].load_path and cfgs["zero"].random_order


def _table(values):
    """{(tip, order, depth): R²} with ``values[depth]`` for order 2, tips A and B."""
    return {(t, o, d): v - (0.01 if t == "B" else 0.0) - (0.1 if o != 2 else 0.0)
            for t in ("A", "B") for o in (1, 2, 3) for d, v in values.items()}


R2 = {
    "ideal": _table({-0.5: 0.92, 0.0: 0.99, 0.5: 0.96}),
    "small": _table({-0.5: 0.91, 0.0: 0.99, 0.5: 0.96}),  # loses 0.01 at -0.5 mm only
    "large": _table({-0.5: 0.82, 0.0: 0.96, 0.5: 0.66}),  # loses 0.10, 0.03, 0.30
    "all": _table({-0.5: 0.80, 0.0: 0.95, 0.5: 0.60}),
}


def test_sources_are_ranked_by_their_mean_loss():
    ranked = ranking(R2)
    assert [name for name, _, _ in ranked] == ["large", "small"]
    name, mean, loss = ranked[0]
    assert mean == pytest.approx((0.10 + 0.03 + 0.30) / 3)
    assert loss == pytest.approx({-0.5: 0.10, 0.0: 0.03, 0.5: 0.30})
    assert ranked[1][2] == pytest.approx({-0.5: 0.01, 0.0: 0.0, 0.5: 0.0})


def test_report_and_chart(tmp_path):
    r2 = {c: {f: cells for f in FEATURES} for c, cells in R2.items()}
    text = report(r2, load_rig("realistic"), ["A", "B"])
    # the order-2 table: ranges over the two tips, and the paper's Table I for A and B
    assert "| large | 0.810–0.820 | 0.950–0.960 | 0.650–0.660 |" in text
    assert "| paper (Table I) | 0.89–0.92 | 0.91–0.92 | 0.71–0.92 |" in text
    assert "| 1 | large | +0.143 |" in text
    # all vs the paper, tip A order 2 at +0.5 mm: 0.60 against 0.92
    assert "| A | 2 | +0.5 | 0.600 | 0.92 | -0.320 |" in text
    assert "| load_path | True | Pestell" in text and "UR5" in text  # the rig's citations
    chart(r2, tmp_path / "b.png", "growth")
    assert (tmp_path / "b.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_input_is_refused_before_any_work(tmp_path, capsys):
    from tactip_sim.commands import main

    from .conftest import ROOT

    scene = str(ROOT / "scenes" / "shadow_fingertip.toml")
    out = tmp_path / "study"
    assert main(["study", "rig", scene, "--out", str(out), "--sources", "robot,wind"]) != 0
    assert "unknown rig source 'wind'" in capsys.readouterr().err
    assert main(["study", "rig", scene, "--out", str(out), "--rig", "nonesuch"]) != 0
    assert "--rig 'nonesuch' is neither a rig file nor a preset" in capsys.readouterr().err
    assert main(["study", "rig", scene, "--out", str(out), "--workers", "0"]) != 0
    assert "--workers=0" in capsys.readouterr().err
    assert not out.exists()
