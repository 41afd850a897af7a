"""The ``tactip press`` command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tactip_sim.commands import main

SCENE = str(Path(__file__).resolve().parents[1] / "scenes" / "shadow_fingertip.toml")
P1 = ["--set", "fidelity.element_order=1"]


def test_press_prints_json(capsys):
    assert main(["press", SCENE, *P1, "--roll", "4", "--pitch", "-2", "--depth", "1.0",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["in_contact"] and out["force_N"] > 0 and out["contact_area_mm2"] > 0
    assert out["pose"] == {"roll_deg": 4.0, "pitch_deg": -2.0, "depth_mm": 1.0,
                           "offset_mm": [0.0, 0.0], "yaw_deg": 0.0}
    assert out["pressure_centre_mm"][0] < 0 and out["pressure_centre_mm"][1] < 0


def test_press_text_with_sphere_and_no_contact(capsys):
    assert main(["press", SCENE, *P1, "--indenter", "sphere", "--radius", "8", "--depth",
                 "0.5"]) == 0
    text = capsys.readouterr().out
    assert "Sphere(radius_mm=8.0)" in text and "force" in text and "centre of pressure" in text
    assert main(["press", SCENE, *P1, "--depth", "-0.5"]) == 0
    assert "no contact" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--roll", "95"], "roll_deg=95 is out of range"),
    (["--depth", "9"], "depth_mm=9 is out of range"),
    (["--indenter", "mesh"], "needs --mesh PATH"),
])
def test_press_bad_input_exits_with_a_message(capsys, argv, message):
    assert main(["press", SCENE, *P1, *argv]) == 1
    assert message in capsys.readouterr().err


def test_press_bad_radius_is_refused_by_the_option_parser(capsys):
    """--radius is checked by argparse (exit status 2), naming the option and its range."""
    with pytest.raises(SystemExit) as exc:
        main(["press", SCENE, *P1, "--indenter", "sphere", "--radius", "-2"])
    assert exc.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "--radius" in err and "-2 is out of range" in err


def test_press_help(capsys):
    with pytest.raises(SystemExit):
        main(["press", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert "--roll" in text and "R_y(pitch) R_x(roll) e_z" in text


def test_press_with_a_mesh_indenter(capsys):
    mesh = str(Path(SCENE).parent / "objects" / "capsule_r4.stl")
    assert main(["press", SCENE, *P1, "--indenter", "mesh", "--mesh", mesh, "--yaw", "30",
                 "--depth", "0.5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["in_contact"] and out["max_penetration_mm"] < 1e-6


def test_press_with_friction_along_a_path(capsys):
    argv = ["press", SCENE, *P1, "--indenter", "sphere", "--radius", "10", "--roll", "6",
            "--depth", "1.0", "--steps", "2", "--json"]
    assert main([*argv, "--friction", "0"]) == 0
    frictionless = json.loads(capsys.readouterr().out)
    assert main([*argv, "--friction", "0.5", "--path", "reorient", "--start", "0", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["load_path"]["path"] == "reorient" and out["load_path"]["friction"] == 0.5
    assert out["in_contact"] and out["max_penetration_mm"] < 1e-6
    # friction along the turn leaves a tangential force the frictionless answer has not
    assert out["force_vector_N"] != pytest.approx(frictionless["force_vector_N"], abs=1e-4)


def test_press_with_friction_and_the_neo_hookean_solver(capsys):
    """The large-deformation solve along a tap with friction, through the command: at
    mu = 0 the frictionless neo-Hookean press (to solver precision); with mu = 0.5 the
    tangential force of the tap differs from it."""
    argv = ["press", SCENE, *P1, "--roll", "3", "--depth", "1.0", "--solver", "neo_hookean",
            "--json"]
    assert main([*argv]) == 0
    direct = json.loads(capsys.readouterr().out)
    assert main([*argv, "--friction", "0", "--path", "tap", "--steps", "2"]) == 0
    tap0 = json.loads(capsys.readouterr().out)
    assert tap0["solver"] == direct["solver"] == "neo_hookean"
    assert tap0["force_vector_N"] == pytest.approx(direct["force_vector_N"], abs=1e-9)
    assert main([*argv, "--friction", "0.5", "--steps", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["load_path"]["friction"] == 0.5 and out["max_penetration_mm"] < 1e-6
    assert out["force_vector_N"] != pytest.approx(direct["force_vector_N"], abs=1e-3)


def test_press_takes_friction_from_the_scene(capsys):
    argv = ["press", SCENE, *P1, "--indenter", "sphere", "--radius", "10", "--roll", "6",
            "--depth", "1.0", "--steps", "2", "--json"]
    assert main([*argv, "--friction", "0.5"]) == 0
    given = json.loads(capsys.readouterr().out)
    assert main([*argv, "--set", "indenter.friction_coefficient=0.5"]) == 0
    scene = json.loads(capsys.readouterr().out)
    for out in (scene, given):
        assert out["load_path"].pop("seconds") > 0
    assert scene["load_path"] == given["load_path"] == {
        "path": "tap", "steps": 2, "friction": 0.5, "start_roll_pitch_deg": None}
    assert scene["force_vector_N"] == given["force_vector_N"]


@pytest.mark.parametrize("argv, message", [
    (["--friction", "-1", "--path", "tap"], "--friction=-1.0 is out of range: allowed [0, 10]"),
    (["--friction", "-0.3"], "--friction=-0.3 is out of range: allowed [0, 10]"),  # no --path
    (["--friction", "0.5", "--steps", "0"], "--steps=0 is out of range: allowed [1, 10000]"),
    (["--friction", "0.5", "--path", "direct"], "--path direct is frictionless"),
    (["--friction", "0.5", "--depth", "-0.5"], "leaves contact"),
])
def test_press_friction_bad_input(capsys, argv, message):
    assert main(["press", SCENE, *P1, *argv]) == 1
    assert message in capsys.readouterr().err
