"""Issue 54 (docs/robustness.md): a Ctrl-C from Dr.Jit's first import to the process's end.

Runs ``tactip render`` (spp 1) with ``-X importtime`` and sends SIGINT OFFSET s after
Dr.Jit's first submodule (``drjit.detail``) has finished importing: while its extension
initialises (~0-0.12 s here), Mitsuba loads and renders, and after the command has written its
files and Python shuts down. Prints how each run ended (one line and 130 is the guarantee)
and where the signal landed: ``[after the output]`` when the command had already printed its
``wrote ...`` line (its work was done), ``[process gone]`` when it had already exited or was
exiting (nothing left to interrupt: the kernel takes ~35 ms to tear down the process after its
``exit_group``, measured with strace, and a signal then is not acted on).

    python benchmarks/ctrl_c_drjit_import.py [--command C] [OFFSET ...]   (default 0, 0.05 ... 0.8)

``--command calibrate`` (``--quick``, one worker) or ``sim2real`` (``--model cop --n 10``)
runs that command's start instead of ``render``; the verdict then also counts the temporary
files left in its output folder (``.tmp`` in the name; there should be none).

An OFFSET written ``wT`` (``w0``, ``w0.01``) sends SIGINT T s after the command's output line
instead: the moment from the command's end to the process's end.

``TACTIP_TREE=/path/to/another/checkout`` runs that checkout's code instead (e.g. a worktree
of an older commit, to compare). The render reads the cache: run it once first so the mesh
and compliance are cached and the runs reach Dr.Jit in seconds.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def exiting(pid: int) -> bool:
    """Whether process ``pid`` has ended or is ending (the kernel's PF_EXITING flag, set when
    it calls exit, field 9 of /proc/PID/stat)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return bool(int(stat.rsplit(")", 1)[1].split()[6]) & 0x4)


COMMANDS = {
    "render": lambda out: ["render", str(ROOT / "scenes" / "shadow_fingertip.toml"), "-o",
                           str(out / "f.png"), "--spp", "1"],
    "calibrate": lambda out: ["calibrate", str(ROOT / "scenes" / "shadow_fingertip.toml"),
                              "--out", str(out), "--quick", "--no-progress", "--workers", "1"],
    "sim2real": lambda out: ["sim2real", str(ROOT / "scenes" / "shadow_fingertip.toml"),
                             "--model", "cop", "--n", "10", "--out", str(out),
                             "--no-progress"],
}


def one_run(offset: float, work: Path, n: int, after_output: bool = False,
            command: str = "render") -> str:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # the output line as it is printed
    tree = os.environ.get("TACTIP_TREE")
    if tree:
        env["PYTHONPATH"] = tree
    out = work / f"run{n}"
    if command == "render":
        out.mkdir()  # -o names a file in it; the other commands make their --out folder
    argv = [sys.executable, "-X", "importtime", "-m", "tactip_sim.commands",
            *COMMANDS[command](out)]
    proc = subprocess.Popen(argv, cwd=work, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wrote = threading.Event()

    def read_stdout() -> None:
        for line in proc.stdout:
            if line.startswith("wrote"):
                wrote.set()

    reader = threading.Thread(target=read_stdout, daemon=True)
    reader.start()
    said, sent, where = [], False, ""
    for line in proc.stderr:
        if not line.startswith("import time:"):
            said.append(line)
        elif line.rstrip().endswith("drjit.detail") and not sent:
            if after_output:
                wrote.wait(120)
            time.sleep(offset)
            gone = proc.poll() is not None or exiting(proc.pid)
            where = (" [process gone]" if gone else
                     " [after the output]" if wrote.is_set() else "")
            proc.send_signal(signal.SIGINT)
            sent = True
    proc.wait()
    reader.join(10)
    err = "".join(said)
    lines = [x for x in said if x.strip()]
    tmp = [f for f in out.rglob("*") if ".tmp" in f.name] if out.is_dir() else []
    if tmp:
        where += f" [{len(tmp)} temporary files left]"
    if not sent:
        return "never reached Dr.Jit"
    if "NameError" in err:
        return "NameError traceback" + where
    if "Traceback" in err:
        return "traceback" + where
    if proc.returncode == 130 and len(lines) == 1 and "interrupted" in lines[0]:
        return "one line, 130" + where
    return f"exit {proc.returncode}: {lines[-1:]}" + where


def main() -> None:
    args = sys.argv[1:]
    command = "render"
    if args[:1] == ["--command"]:
        command, args = args[1], args[2:]
    offsets = args or [f"{0.05 * i:.2f}" for i in range(17)]
    counts: Counter = Counter()
    with tempfile.TemporaryDirectory() as d:
        for n, arg in enumerate(offsets):
            after_output = arg.startswith("w")
            offset = float(arg.lstrip("w"))
            verdict = one_run(offset, Path(d), n, after_output, command)
            counts[verdict] += 1
            where = "after the output" if after_output else "after drjit.detail"
            print(f"+{offset:.2f} s {where}: {verdict}", flush=True)
    print(dict(counts))


if __name__ == "__main__":
    main()
