"""Time perception's first frames with an empty and with a filled Numba cache.

    python benchmarks/bench_perception_compile.py

Perception's compiled kernels (``perception/*_kernels.py``, each beside the module that calls
it) are compiled on first use and cached on disk. This copies the ``perception`` package into a
temporary folder (no ``__pycache__``), and in two fresh processes in turn times ``import
perception`` and a ``FeaturePipeline`` built on a synthetic rest frame processing one frame: the
first process compiles every kernel the pipeline uses, the second loads them from the cache the
first wrote.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import time
t0 = time.perf_counter()
import perception as pc
from perception.synthetic import render_markers
t1 = time.perf_counter()
rest = render_markers(pc.hex_lattice(97, 36.0, (319.5, 239.5)), rng=0, diameter_px=20.0).image
t2 = time.perf_counter()
pipe = pc.FeaturePipeline(rest, expected_count=97)
pipe.process(rest)
t3 = time.perf_counter()
print(f"import {t1 - t0:.2f} s, rest frame and one frame {t3 - t2:.2f} s")
"""


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(ROOT / "perception", Path(tmp) / "perception",
                        ignore=shutil.ignore_patterns("__pycache__"))
        for label in ("empty cache (compiles)", "filled cache (loads)"):
            out = subprocess.run([sys.executable, "-c", _CHILD], cwd=tmp, capture_output=True,
                                 text=True, check=True)
            print(f"{label:24s} {out.stdout.strip()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
