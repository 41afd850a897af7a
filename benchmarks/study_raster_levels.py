"""The fidelity study of the raster cap layer's levels against the reference's rendering and
perception on linear physics (docs/speed.md, issue 21).

    python benchmarks/study_raster_levels.py [--out docs/speed/fidelity] [--scene SCENE]

Runs ``tactip_lab.studies.fidelity.run_fidelity_study`` on the levels ``balanced``,
``1 frame``, ``raster caps``, ``raster caps + 1 frame``, ``image mean`` and ``raster caps +
image mean``. The reference level is the
``reference`` preset (Lambert caps, 16 spp, 60 frames) with ``material_model = "linear"``: every
level then shares one FEM result and the errors are those of the render and perception path
alone. (The full study, ``tactip study fidelity``, uses the neo-Hookean reference press, ~10 min
per pose.) About 6 min on the shared 2-core machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

LEVELS = ["balanced", "1 frame", "raster caps", "raster caps + 1 frame", "image mean",
          "raster caps + image mean"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "speed" / "fidelity"),
                    help="output folder (summary.json, report.md, levels.csv, front.png)")
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "shadow_fingertip.toml"),
                    help="scene file")
    args = ap.parse_args()

    import tactip_sim as ts
    from tactip_lab.studies.fidelity import REFERENCE, Level, run_fidelity_study

    scene = ts.load_scene(args.scene)
    ref = Level(REFERENCE, "preset", {"fidelity": {"material_model": "linear"}},
                base=REFERENCE, note="reference rendering and perception, linear physics")
    run_fidelity_study(scene, args.out, levels=LEVELS, reference=ref)
    print(f"results in {args.out}/")


if __name__ == "__main__":
    main()
