"""The scene arguments every scene-reading command shares: the SCENE positional, ``--fidelity``
and ``--set`` overrides (used by this floor's commands and by the subcommands that
``calibration`` and ``perception`` register)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from ..scene import Scene, SceneError, apply_preset, defaults_notice, load_scene, replace_in

DEFAULT_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "shadow_fingertip.toml"


def parse_overrides(pairs: Sequence[str]) -> dict[str, object]:
    """``["camera.tilt_deg=6", "pins.model=\\"embedded\\""]`` -> ``{"camera.tilt_deg": 6.0, ...}``.
    Values are parsed as TOML (bare words are taken as strings)."""
    import tomllib

    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or "." not in key:
            raise SceneError(f"--set {pair!r} must look like section.key=value")
        try:
            out[key.strip()] = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = raw
    return out


def add_scene_argument(p: argparse.ArgumentParser, *, optional: bool = False,
                       auto: bool = False) -> None:
    """The SCENE positional, ``--fidelity`` and ``--set`` overrides, shared by every
    scene-reading command. ``auto``: the command also accepts ``--fidelity auto``."""
    if optional:
        p.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE),
                       help=f"scene file (default: {DEFAULT_SCENE.relative_to(Path.cwd())})"
                       if DEFAULT_SCENE.is_relative_to(Path.cwd()) else "scene file")
    else:
        p.add_argument("scene", help="scene file (.toml), e.g. scenes/shadow_fingertip.toml")
    p.add_argument("--fidelity", metavar="PRESET",
                   help="apply a fidelity preset of the scene (default: none, the scene's own "
                   "keys: raster caps, frames averaged as one image): paper (the paper's "
                   "averaging with Mitsuba caps; also named balanced), fast, reference or one "
                   "the scene defines" + (", or auto (the cheapest level of a fidelity study "
                   "that meets the tolerance)" if auto else "") + "; --set overrides it")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set camera.tilt_deg=6 (repeatable)")


def load_scene_args(args: argparse.Namespace) -> Scene:
    """The scene of a command's arguments: the file, then ``--fidelity``, then ``--set``
    overrides on top. A file that leaves keys at their defaults without ending in ``[end]``
    (as a file cut short does) gets a one-line notice on stderr naming it and the keys."""
    overrides = parse_overrides(args.overrides)
    scene = load_scene(args.scene, overrides)
    name = getattr(args, "fidelity", None)
    notice = defaults_notice(args.scene, overrides,
                             name if name is not None and name in scene.presets else None)
    if notice:
        print(f"tactip: note: {notice}", file=sys.stderr)
    if name is None:
        return scene
    if name == "auto":
        raise SceneError("--fidelity auto is only accepted by the calibration commands "
                         "(calibrate, sweep), which read a fidelity study")
    return with_overrides(apply_preset(scene, name), overrides)


def with_overrides(scene: Scene, overrides: dict[str, object]) -> Scene:
    """``scene`` with ``{"section.key": value}`` overrides applied on top (validated), e.g. to
    let ``--set`` win over a fidelity level applied after the file was read."""
    by_section: dict[str, dict[str, object]] = {}
    for dotted, value in overrides.items():
        section, _, key = dotted.partition(".")
        by_section.setdefault(section, {})[key] = value
    return replace_in(scene, **by_section) if by_section else scene


def _range_text(lo: float | None, hi: float | None, lo_open: bool) -> str:
    left = "(" if lo_open or lo is None else "["
    right = ")" if hi is None else "]"
    def text(v: float) -> str:
        return str(v) if isinstance(v, int) else format(v, "g")

    return (f"{left}{'-inf' if lo is None else text(lo)}, "
            f"{'inf' if hi is None else text(hi)}{right}")


def int_in(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer in ``[lo, hi]`` (None = unbounded). A bad value is
    reported by argparse with the option's name and the allowed range, e.g.
    ``argument --spp: -4 is out of range: allowed [1, 4096]`` (exit status 2)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not an integer: allowed {_range_text(lo, hi, False)}") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(
                f"{value} is out of range: allowed {_range_text(lo, hi, False)}")
        return value

    parse.__name__ = "integer"
    parse.allowed = (lo, hi, False)  # type: ignore[attr-defined]  (read by the fuzz tests)
    return parse


def float_in(lo: float | None = None, hi: float | None = None, *,
             lo_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type``: a finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``;
    None = unbounded); NaN and infinities are refused, naming the option and the range."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a number: allowed {_range_text(lo, hi, lo_open)}") from None
        bad = not math.isfinite(value)
        bad = bad or (lo is not None and (value <= lo if lo_open else value < lo))
        bad = bad or (hi is not None and value > hi)
        if bad:
            raise argparse.ArgumentTypeError(
                f"{text} is out of range: allowed {_range_text(lo, hi, lo_open)}")
        return value

    parse.__name__ = "number"
    parse.allowed = (lo, hi, lo_open)  # type: ignore[attr-defined]
    return parse


def scene_key_type(dotted: str) -> Callable[[str], float]:
    """An argparse ``type`` checking a value against scene key ``dotted``'s allowed range
    (e.g. ``--spp`` against ``imaging.spp``): one range for the key and the option."""
    from ..scene.load import key_spec

    spec = key_spec(dotted)
    if spec.kind == "int":
        return int_in(None if spec.lo is None else int(spec.lo),
                      None if spec.hi is None else int(spec.hi))
    return float_in(spec.lo, spec.hi, lo_open=spec.lo_open)


def png_path(value: str) -> Path:
    """An argparse ``type`` for a frame's output: a name ending in ``.png`` (or none), so the
    file written is the one named (``-o x.jpg`` used to write ``x.png``)."""
    path = Path(value)
    if path.suffix.lower() not in ("", ".png"):
        raise argparse.ArgumentTypeError(
            f"{value!r}: a frame is written as PNG, with its ground truth beside it (.json, "
            ".csv); give a name ending in .png")
    return path
