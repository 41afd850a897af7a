"""The tactip command line: help on every command, scene printing, mesh statistics, errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib

import pytest

from tactip_sim.commands import main

from .conftest import SCENES


def _subcommands(capsys) -> list[str]:
    """The subcommands ``tactip --help`` lists (one per line, indented under COMMAND)."""
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    return re.findall(r"^    ([a-z][\w-]*)", text, flags=re.MULTILINE)


def test_help_on_every_command(capsys):
    names = _subcommands(capsys)
    # this package's commands and those registered by calibration and perception
    assert {"scene", "mesh", "cache", "press", "render", "validate-lens", "calibrate"} <= set(names)
    for name in [None, *names]:
        with pytest.raises(SystemExit) as exc:
            main(["--help"] if name is None else [name, "--help"])
        assert exc.value.code == 0
        out = capsys.readouterr().out
        assert "usage: tactip" in out


def test_scene_command_prints_resolved_toml(capsys):
    assert main(["scene", str(SCENES / "shadow_fingertip.toml"), "--set",
                 "camera.tilt_deg=5"]) == 0
    out = capsys.readouterr().out
    data = tomllib.loads(out)
    assert data["camera"]["tilt_deg"] == 5.0
    assert data["pins"]["count"] == 97


def test_bad_scene_gives_exit_2_and_names_key(capsys):
    rc = main(["scene", str(SCENES / "shadow_fingertip.toml"), "--set", "skin.poisson_ratio=0.5"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "skin.poisson_ratio=0.5 is out of range" in err


def test_mesh_command_reports_counts_and_quality(capsys, mesh):
    assert main(["mesh", str(SCENES / "shadow_fingertip.toml"), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["nodes"] == len(mesh.nodes) and stats["tets"] == len(mesh.tets)
    assert stats["pins"] == 97 and stats["surface_watertight"] == 1
    assert stats["min_dihedral_deg"] > 0


def test_module_runs_as_the_command():
    res = subprocess.run([sys.executable, "-m", "tactip_sim.commands", "--help"],
                         capture_output=True, text=True, check=False)
    assert res.returncode == 0 and "validate-lens" in res.stdout and "usage: tactip" in res.stdout


def test_ctrl_c_gives_a_message_and_exit_code_130(monkeypatch, capsys):
    """Ctrl-C in any command: no traceback, the shell's 130, and how to continue."""
    import tactip_sim.commands.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "load_scene_args", interrupted)  # Ctrl-C while reading the scene
    assert main(["scene", str(SCENES / "shadow_fingertip.toml")]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "same command again" in err and "Traceback" not in err


def test_render_with_pins_on_the_default_scene_uses_mitsubas_caps(tmp_path, capsys):
    """The default raster cap layer draws caps only: ``--pins`` renders with Mitsuba's caps
    (and says so) instead of refusing the default scene."""
    out = tmp_path / "f.png"
    assert main(["render", str(SCENES / "shadow_fingertip.toml"), "--depth", "0.5", "--spp",
                 "1", "--no-noise", "-o", str(out), "--pins"]) == 0
    assert "imaging.cap_layer = mitsuba" in capsys.readouterr().err
    truth = json.loads(out.with_suffix(".json").read_text())
    assert out.stat().st_size > 1000 and sum(truth["visible"]) > 80
