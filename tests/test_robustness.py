"""Issue 15, the two defects left open in docs/robustness.md ("What is still open"):

* a Ctrl-C early in a ``tactip`` run printed Python's traceback (the console script imported
  the package, and the package the scene module, before any of the tool's code ran);
* a scene file cut at a line boundary is valid TOML: the keys it lost took their defaults
  and nothing said so.

Each test failed on the code before the fix.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import pytest

from tactip_sim.commands import main
from tactip_sim.scene import SceneError, load_scene

from .conftest import ROOT, SCENES, sigint_as_at_a_terminal

SCENE = SCENES / "shadow_fingertip.toml"


# --- a Ctrl-C at any moment of a run -----------------------------------------------------

def _console_script(tmp_path: Path) -> Path:
    """The script pip writes for ``[project.scripts] tactip`` (its template, with the entry
    named in pyproject.toml), so the entry point a fresh install runs is the one tested."""
    entry = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]["tactip"]
    module, _, func = entry.partition(":")
    path = tmp_path / "tactip"
    path.write_text(
        "import re\nimport sys\n"
        f"from {module} import {func}\n"
        "if __name__ == '__main__':\n"
        "    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])\n"
        f"    sys.exit({func}())\n")
    return path


def _env(tmp_path: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "TACTIP_CACHE_DIR": str(tmp_path / "cache")}


def _interrupted_run(cmd: list[str], tmp_path: Path, delay: float) -> tuple[int | None, str]:
    """Run ``cmd`` (a Python command line) and send it SIGINT ``delay`` s after Python's own
    start-up ended (``site`` imported: ``-X importtime`` reports it); before that no code of
    the tool runs (docs/robustness.md measures that window). Returns (exit status or None if
    the run had already ended, stderr without the import-time lines)."""
    with subprocess.Popen([sys.executable, "-X", "importtime", *cmd], cwd=tmp_path,
                          env=_env(tmp_path), stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True,
                          preexec_fn=sigint_as_at_a_terminal) as proc:
        lines: list[str] = []
        started = threading.Event()

        def read() -> None:
            for line in proc.stderr:
                lines.append(line)
                if line.rstrip().endswith("| site"):
                    started.set()
            started.set()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            assert started.wait(60), "Python did not start"
            time.sleep(delay)
            ended_before = proc.poll() is not None
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
        reader.join(10)
    err = "".join(line for line in lines if not line.startswith("import time:"))
    return (None if ended_before else proc.returncode), err


def _tool_frames(err: str) -> list[str]:
    """The frames of a traceback in ``err`` that are the tool's code (a file of this project):
    a Ctrl-C there must never print a traceback. Frames of Python's own start-up (``<frozen
    runpy>``) and of the console script pip writes are the window docs/robustness.md measures
    and leaves open; under load a SIGINT 0.02 s after ``site`` can land there."""
    return [line for line in err.splitlines() if line.strip().startswith('File "')
            and str(ROOT) in line]


@pytest.mark.parametrize("entry, delays", [("console script", [0.02, 0.3]),
                                           ("python -m", [0.02, 0.05, 0.1, 0.2, 0.5])])
def test_ctrl_c_early_in_a_run_ends_with_one_line_and_130(tmp_path, entry, delays):
    """Before the fix, a Ctrl-C 0.02-0.1 s after Python's start-up (the scene module, numpy's
    and the package's imports) ended with Python's KeyboardInterrupt traceback."""
    launcher = ([str(_console_script(tmp_path))] if entry == "console script"
                else ["-m", "tactip_sim.commands"])
    for delay in delays:
        rc, err = _interrupted_run([*launcher, "scene", str(SCENE)], tmp_path, delay)
        assert not _tool_frames(err), f"{entry}, SIGINT {delay} s in:\n{err}"
        if "Traceback" in err:  # Python's own steps before the tool's first line (runpy, the
            continue            # console script's import line): documented, not covered
        if rc is None:  # the command had finished first (a fast machine): nothing to interrupt
            continue
        assert rc == 130, f"{entry}, SIGINT {delay} s in: exit {rc}\n{err}"
        said = [line for line in err.splitlines() if line.strip()]
        assert len(said) == 1 and "tactip: interrupted" in said[0], err


def test_ctrl_c_while_python_exits_ends_with_one_line_and_130(tmp_path):
    """After the command returned, Python joins threads and runs exit handlers (a library's
    may be slow): a Ctrl-C there raised KeyboardInterrupt inside them, a traceback ("Exception
    ignored in: <module 'threading'>"). Here a thread keeps Python's exit waiting."""
    code = ("import sys, threading, time\n"
            "from tactip_sim.commands.launch import main\n"
            "threading.Thread(target=threading.Event().wait).start()  # never ends\n"
            f"code = main(['scene', {str(SCENE)!r}])\n"
            "print('returned', code, file=sys.stderr, flush=True)\n"
            "sys.exit(code)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=tmp_path, env=_env(tmp_path),
                            preexec_fn=sigint_as_at_a_terminal,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()
        assert first.startswith("returned 0"), first + proc.stderr.read()
        time.sleep(0.2)  # Python is now waiting for the thread
        proc.send_signal(signal.SIGINT)
        # the thread never ends: a process that waited for it would never exit by itself (the
        # timeout only guards the test run; the assertions are on how the process ended)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err  # it ended by itself, with the interrupt's status
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert err.strip().splitlines() == ["tactip: interrupted while exiting (the command had ended)"]
    assert tomllib.loads(out)["tolerances"]["stiffness_rel"] == 0.05  # the output is all there


def test_the_entry_point_loads_nothing_before_it_takes_over_ctrl_c():
    """The console script imports ``tactip_sim`` and ``tactip_sim.commands`` before the entry
    function runs; those import nothing at their top (the scene module, numpy and the rest
    load once Ctrl-C is handled), so the unprotected part after Python's start-up stays ~2 ms.
    The package API still works as before, names loaded on first use."""
    code = ("import sys, tactip_sim.commands.launch\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('tactip_sim', 'numpy', 'scipy', 'trimesh', 'tomllib', 'dataclasses')))\n"
            "import tactip_sim as ts, tactip_sim.commands as tc\n"
            "print(ts.load_scene, ts.Scene, ts.SceneError, tc.main, tc.add_scene_argument)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    first = res.stdout.splitlines()[0]
    assert first == ("['tactip_sim', 'tactip_sim._lazy', 'tactip_sim.commands', "
                     "'tactip_sim.commands.interrupts', 'tactip_sim.commands.launch']")
    assert "function load_scene" in res.stdout and "function main" in res.stdout


# --- a scene file cut at a line boundary -------------------------------------------------

def _cut_after(tmp_path: Path, last_line: str) -> Path:
    """``scenes/shadow_fingertip.toml`` cut after the line that starts with ``last_line``."""
    lines = SCENE.read_text().splitlines(keepends=True)
    n = next(i for i, line in enumerate(lines) if line.startswith(last_line)) + 1
    path = tmp_path / "cut.toml"
    path.write_text("".join(lines[:n]))
    return path


def test_a_scene_file_cut_at_a_line_boundary_is_named_with_the_keys_it_lost(tmp_path, capsys):
    path = _cut_after(tmp_path, 'kind = "plate"')  # in [indenter]: 3 sections and 3 keys lost
    assert main(["scene", str(path)]) == 0           # still loads (a short file is allowed)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert str(path) in err
    for key in ("indenter.radius_mm", "indenter.length_mm", "indenter.mesh",
                "[fidelity]", "[protocol]", "[tolerances]"):
        assert key in err, key
    assert "[pad]" not in err and "camera." not in err  # only what was lost


def test_every_line_cut_of_the_bundled_scene_that_loads_is_reported(tmp_path):
    """Cut after each line in turn: every cut that still loads, and loads as another scene
    than the whole file, names the file and a key that changed."""
    from tactip_sim.scene import defaults_notice, scene_to_dict

    whole = scene_to_dict(load_scene(SCENE))
    lines = SCENE.read_text().splitlines(keepends=True)
    path = tmp_path / "cut.toml"
    loaded = 0
    for n in range(1, len(lines)):
        path.write_text("".join(lines[:n]))
        try:
            cut = scene_to_dict(load_scene(path))
        except SceneError:
            continue  # refused (e.g. nothing set yet): not silent
        loaded += 1
        changed = [f"{s}.{k}" for s, table in whole.items() if isinstance(table, dict)
                   for k, v in table.items() if cut[s].get(k) != v]
        notice = defaults_notice(path)
        if changed:
            assert str(path) in notice, (n, changed)
            assert any(key in notice or f"[{key.split('.')[0]}]" in notice for key in changed)
    assert loaded > 80


def test_the_bundled_scenes_load_without_a_notice(capsys):
    for path in sorted(SCENES.glob("*.toml")):
        assert main(["scene", str(path)]) == 0, path
        assert capsys.readouterr().err == "", path


def test_a_short_file_ending_in_end_is_meant_and_set_keys_count(tmp_path, capsys):
    short = '[pad]\nshape = "block"\n[pins]\ncount = 0\n'
    path = tmp_path / "block.toml"
    path.write_text(short)
    assert main(["scene", str(path)]) == 0
    err = capsys.readouterr().err
    assert "block.toml" in err and "pad.height_mm" in err and "[tolerances]" in err
    assert "[end]" in err  # the notice says how to mark a short file as meant
    path.write_text(short + "\n[end]  # the rest defaults on purpose\n\n# a comment\n")
    assert main(["scene", str(path)]) == 0
    assert capsys.readouterr().err == ""
    # --set gives a key: it is no longer reported
    cut = _cut_after(tmp_path, "camera_tilt_deg")
    assert main(["scene", str(cut), "--set", "tolerances.stiffness_rel=0.05"]) == 0
    err = capsys.readouterr().err
    assert "stiffness_rel" not in err and "leaves" not in err


def test_an_end_line_that_is_not_the_last_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[pad]\nshape = "block"\n[end]\n[pins]\ncount = 0\n')
    with pytest.raises(SceneError, match=r"s\.toml.*\[end\] must be its last line"):
        load_scene(path)
    path.write_text('[pad]\nshape = "block"\n[pins]\ncount = 0\n[end]\nx = 1\n')
    with pytest.raises(SceneError, match=r"s\.toml.*\[end\] must be its last line"):
        load_scene(path)


def test_a_cut_in_the_preset_tables_at_a_files_end_is_reported(tmp_path, capsys):
    """Preset settings have no defaults to miss: a file that ends in preset tables needs the
    [end] line (the identified scenes and what ``tactip identify`` writes have it)."""
    source = SCENES / "tactip_331_identified.toml"
    lines = source.read_text().splitlines(keepends=True)
    assert lines[-1] == "[end]\n"
    path = tmp_path / "identified.toml"
    path.write_text("".join(lines[:-3]))  # cut inside [presets.reference.protocol]
    assert main(["scene", str(path)]) == 0
    err = capsys.readouterr().err
    assert "identified.toml" in err and "preset" in err and "[end]" in err


def test_what_tactip_scene_prints_is_a_whole_scene_file(tmp_path, capsys):
    assert main(["scene", str(SCENES / "hertz_block.toml")]) == 0
    printed = capsys.readouterr().out
    path = tmp_path / "resolved.toml"
    path.write_text(printed)
    assert main(["scene", str(path)]) == 0
    again = capsys.readouterr()
    assert again.err == "" and again.out.split("\n", 1)[1] == printed.split("\n", 1)[1]
    path.write_text("".join(printed.splitlines(keepends=True)[:-2]))  # the [end] line lost
    assert main(["scene", str(path)]) == 0
    assert "resolved.toml" in capsys.readouterr().err


def test_ctrl_c_while_the_launcher_loads_ends_with_one_line_and_130(tmp_path):
    """The Ctrl-C of the flaky window above, made certain: a KeyboardInterrupt raised by the
    import of the launcher itself (an import hook raises it), as SIGINT under load landed
    once, 20 ms after ``site``. Through ``python -m`` that ended in a traceback."""
    code = ("import runpy, sys\n"
            "class Interrupt:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'tactip_sim.commands.launch':\n"
            "            raise KeyboardInterrupt\n"
            "sys.meta_path.insert(0, Interrupt())\n"
            "sys.argv = ['tactip', 'scene']\n"
            "runpy.run_module('tactip_sim.commands', run_name='__main__', alter_sys=True)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=_env(tmp_path),
                          capture_output=True, text=True, timeout=120)
    said = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 130, proc.stderr
    assert len(said) == 1 and "tactip: interrupted" in said[0], proc.stderr


_HALF_LOADED = """
import atexit, sys, types
from tactip_sim.commands import cli, launch
cli.build_parser = lambda: None
def run(parser, argv):
    if sys.argv[1] == "drjit":  # what a Ctrl-C during Dr.Jit's extension import leaves
        sys.modules["drjit.detail"] = types.ModuleType("drjit.detail")
    print("tactip render: interrupted", file=sys.stderr)
    return 130
cli.run = run
atexit.register(lambda: print("finalised", flush=True))
sys.exit(launch.main([]))
"""


@pytest.mark.parametrize("loaded", ["drjit", "nothing"])
def test_an_interrupt_while_drjit_loads_skips_pythons_finalisation(loaded):
    """A Ctrl-C while Dr.Jit's binary extension initialises left it half set up, and Python's
    finalisation then aborted (SIGABRT, "Fatal Python error: PyThreadState_Get"; measured in 2
    of 15 runs interrupted 0.25-0.27 s into it). After such an interrupt the process ends at
    once with its status (no exit handler runs); otherwise Python finalises as usual."""
    # SIGINT as at a terminal: a suite run in the background (`cmd &`) starts its children
    # with it ignored, and the launcher then leaves SIGINT (and this check) alone
    proc = subprocess.run([sys.executable, "-c", _HALF_LOADED, loaded], capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120,
                          preexec_fn=sigint_as_at_a_terminal)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == "tactip render: interrupted"
    assert ("finalised" in proc.stdout) == (loaded == "nothing")
