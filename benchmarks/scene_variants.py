"""What the scene-variant benchmarks share (``sim2real_field_profile.py``,
``sim2real_edge_localisation.py``): their command line (named variants of the identified
331-pin scene, a real folder to compare with) and the variant scenes themselves."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "tactip_331_identified.toml"


def parse(description: str, variants: dict[str, dict], real: str, real_help: str,
          argv: list[str] | None = None, *, flags: dict[str, str] | None = None,
          paths: dict[str, tuple[str, str]] | None = None) -> argparse.Namespace:
    """``VARIANT ...`` (names of ``variants``; none: all), ``--real DIR`` (default
    ``../shared/real/<real>``), ``--no-real``, the caller's own on/off ``flags`` (name: help)
    and options taking a path, ``paths`` (name: (metavar, help); None when not given); an
    unknown variant is an error naming the choices. Puts the project's root on ``sys.path``
    for the imports that follow."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("variants", nargs="*", metavar="VARIANT",
                   help=f"scene variants (default all): {', '.join(variants)}")
    p.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real" / real,
                   help=real_help)
    p.add_argument("--no-real", action="store_true", help="skip the real taps")
    for flag, text in (flags or {}).items():
        p.add_argument(flag, action="store_true", help=text)
    for flag, (metavar, text) in (paths or {}).items():
        p.add_argument(flag, type=Path, default=None, metavar=metavar, help=text)
    args = p.parse_args(argv)
    unknown = [v for v in args.variants if v not in variants]
    if unknown:
        p.error(f"unknown variant {unknown[0]!r}: choose from {', '.join(variants)}")
    args.variants = args.variants or list(variants)
    sys.path.insert(0, str(ROOT))
    return args


def scenes(names: list[str], variants: dict[str, dict]) -> Iterator[tuple[str, Any]]:
    """(name, scene) of each variant: the identified scene's ``fast`` preset with the
    variant's keys replaced; each variant's time goes to stderr once its caller is done
    with it."""
    import tactip_sim as ts
    from tactip_sim.scene import apply_preset, replace_in

    base = apply_preset(ts.load_scene(SCENE), "fast")
    for name in names:
        t0 = time.perf_counter()
        over = variants[name]
        yield name, (replace_in(base, **over) if over else base)
        print(f"({name}: {time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
