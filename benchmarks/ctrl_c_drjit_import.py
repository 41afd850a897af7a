"""Issue 54 (docs/robustness.md): a Ctrl-C while Dr.Jit's binary extension loads.

Runs ``tactip render`` (spp 1) with ``-X importtime`` and sends SIGINT OFFSET s after
Dr.Jit's first submodule (``drjit.detail``) has finished importing, i.e. while its extension
initialises; prints how each run ended (one line and 130 is the guarantee).

    python benchmarks/ctrl_c_drjit_import.py [OFFSET ...]      (default 0, 0.02 ... 0.28)

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
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def one_run(offset: float, work: Path) -> str:
    env = dict(os.environ)
    tree = os.environ.get("TACTIP_TREE")
    if tree:
        env["PYTHONPATH"] = tree
    argv = [sys.executable, "-X", "importtime", "-m", "tactip_sim.commands", "render",
            str(ROOT / "scenes" / "shadow_fingertip.toml"), "-o", str(work / "f.png"),
            "--spp", "1"]
    if not tree:
        argv.append("--overwrite")
    proc = subprocess.Popen(argv, cwd=work, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    said, sent = [], False
    for line in proc.stderr:
        if not line.startswith("import time:"):
            said.append(line)
        elif line.rstrip().endswith("drjit.detail") and not sent:
            time.sleep(offset)
            proc.send_signal(signal.SIGINT)
            sent = True
    proc.wait()
    err = "".join(said)
    lines = [x for x in said if x.strip()]
    if not sent:
        return "never reached Dr.Jit"
    if "NameError" in err:
        return "NameError traceback"
    if "Traceback" in err:
        return "traceback"
    if proc.returncode == 130 and len(lines) == 1:
        return "one line, 130"
    return f"exit {proc.returncode}: {lines[-1:]}"


def main() -> None:
    offsets = [float(x) for x in sys.argv[1:]] or [0.02 * i for i in range(15)]
    counts: Counter = Counter()
    with tempfile.TemporaryDirectory() as d:
        for offset in offsets:
            verdict = one_run(offset, Path(d))
            counts[verdict] += 1
            print(f"+{offset:.2f} s: {verdict}", flush=True)
    print(dict(counts))


if __name__ == "__main__":
    main()
