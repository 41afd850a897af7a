"""The tactip command line: help on every command, scene printing, mesh statistics, errors."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib

import pytest

from tactip_sim.cli import build_parser, main

from .conftest import SCENES


def _subcommands():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sorted(sub.choices)


def test_help_on_every_command(capsys):
    for name in [None, *_subcommands()]:
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


def test_console_script_runs():
    res = subprocess.run([sys.executable, "-m", "tactip_sim.cli", "--help"], capture_output=True,
                         text=True, check=False)
    assert res.returncode == 0 and "mesh" in res.stdout


def test_ctrl_c_gives_a_message_and_exit_code_130(monkeypatch, capsys):
    """Ctrl-C in any command: no traceback, the shell's 130, and how to continue."""
    import tactip_sim.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_cmd_scene", interrupted)
    assert main(["scene", str(SCENES / "shadow_fingertip.toml")]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "same command again" in err and "Traceback" not in err
