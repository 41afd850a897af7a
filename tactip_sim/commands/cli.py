"""The ``tactip`` command line: :func:`main` and :func:`build_parser`.

The top floor of ``tactip_sim``: it may import every layer below, nothing below imports it.
Its own subcommands are ``scene``, ``mesh`` and ``cache`` (here), ``press``
(:mod:`.press`), ``render`` (:mod:`.render`) and ``validate-lens`` (:mod:`.validate_lens`); the
other packages add theirs through the ``tactip.commands`` entry-point group
(``register(subparsers)``), so ``tactip_sim`` never imports ``perception`` or ``calibration``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Callable, Iterator, Sequence
from importlib import import_module
from importlib.metadata import entry_points

from ..scene import SceneError
from .args import add_scene_argument, load_scene_args
from .interrupts import caused_by_interrupt
from .outputs import declare

_OWN_COMMANDS = ("press", "render", "validate_lens")
"""Modules of this floor with ``register(subparsers)``, in the order of ``tactip --help``;
imported by :func:`build_parser`, so that a Ctrl-C during their (heavy) imports reaches
:func:`main`'s handler."""


def _cmd_scene(args: argparse.Namespace) -> int:
    from ..scene import scene_hash, scene_to_toml

    scene = load_scene_args(args)
    print(f"# scene {scene.name!r} from {scene.source} (hash {scene_hash(scene)})")
    print(scene_to_toml(scene), end="")
    return 0


def _cmd_mesh(args: argparse.Namespace) -> int:
    from ..geometry import build_pad
    from ..mesh import tetrahedralise

    scene = load_scene_args(args)
    pad = build_pad(scene)
    mesh = tetrahedralise(scene, use_cache=not args.no_cache)
    s = mesh.summary()
    if args.bundle:
        from ..mesh.tetra import bundled_path

        target = mesh.save(bundled_path(mesh.key))  # the stored form tetrahedralise reads
        print(f"bundled {target}")
    s["pins"] = len(pad.markers_mm)
    s["surface_watertight"] = int(pad.surface.is_watertight)
    if pad.outer is not None:
        s["skin_volume_exact_mm3"] = pad.skin_volume_mm3
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    src = "loaded from cache" if mesh.from_cache else "built"
    print(f"mesh {s['key']} ({src} in {s['seconds']:.3f} s)")
    print(f"  nodes {s['nodes']}, tets {s['tets']} (skin {s['skin_tets']}, gel {s['gel_tets']})")
    print(f"  volume {s['volume_mm3']:.1f} mm3, skin {s['skin_volume_mm3']:.1f} mm3"
          + (f" (exact shell {s['skin_volume_exact_mm3']:.1f})" if pad.outer is not None else ""))
    print(f"  dihedral angles {s['min_dihedral_deg']:.1f}..{s['max_dihedral_deg']:.1f} deg, "
          f"volume ratio min {s['min_volume_ratio']:.3f} mean {s['mean_volume_ratio']:.3f}")
    print(f"  pins {s['pins']}, surface watertight: {bool(s['surface_watertight'])}")
    return 0


def _cmd_cache(args: argparse.Namespace) -> int:
    from .. import cache

    if args.action == "clear":
        d, n = cache.clear()
        print(f"removed {n} files from {d}")
    else:
        d = cache.cache_dir()
        files = cache.entries()  # the tool's entries only (TACTIP_CACHE_DIR=/ walked it all)
        size = sum(p.stat().st_size for p in files)
        print(f"{d}: {len(files)} files, {size / 1e6:.1f} MB")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``tactip`` parser with every subcommand (this floor's and the registered ones)."""
    parser = argparse.ArgumentParser(
        prog="tactip",
        description="Simulate, render and calibrate an optical TacTip fingertip.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("scene", help="print the resolved, validated scene",
                       description="Validate a scene file and print it with every default filled.")
    add_scene_argument(p)
    p.set_defaults(func=_cmd_scene)
    declare(p, "scene", inputs={"scene": "toml"})

    p = sub.add_parser("mesh", help="build or load the tetrahedral mesh and print its statistics",
                       description="Tetrahedralise the pad (cached on disk) and report counts "
                       "and element quality.")
    add_scene_argument(p)
    p.add_argument("--no-cache", action="store_true", help="rebuild and do not store the mesh")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.add_argument("--bundle", action="store_true",
                   help="copy the mesh into scenes/meshes/ so it ships with the project "
                   "(pytetwild is not deterministic: bundling makes results reproducible)")
    p.set_defaults(func=_cmd_mesh)
    declare(p, "mesh", inputs={"scene": "toml"})

    p = sub.add_parser("cache", help="show or clear the on-disk cache",
                       description="Meshes, factorisations and compliances are cached on disk.")
    p.add_argument("action", choices=["info", "clear"], help="info: size; clear: delete all")
    p.set_defaults(func=_cmd_cache)

    for name in _OWN_COMMANDS:
        import_module(f"{__package__}.{name}").register(sub)
    for ep in sorted(entry_points(group="tactip.commands"), key=lambda e: e.name):
        register: Callable[[argparse._SubParsersAction], None] = ep.load()
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``tactip`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code: 0, 1
    (an error, printed), 2 (a scene error, printed), 130 (interrupted: Ctrl-C) or 143
    (terminated: SIGTERM, handled as an interrupt so temporary files are removed).

    For in-process callers; the program itself starts in :func:`.launch.main`, which also
    covers a Ctrl-C while this module loads and while Python exits."""
    # loading the subcommands imports their packages; some libraries import their optional
    # parts under `except BaseException` (trimesh), which swallowed a Ctrl-C: the command then
    # ran to the end. So a Ctrl-C here is held until the imports are done.
    with _held_interrupt() as held:
        parser = build_parser()
    if held:
        print("\ntactip: interrupted before the command started", file=sys.stderr)
        return 130
    return run(parser, argv)


def run(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` with ``parser`` (from :func:`build_parser`) and run the command; returns
    its exit code as :func:`main` does."""
    args = parser.parse_args(argv)
    with _sigterm_interrupts() as terminated:
        return _run(args, terminated)


def _run(args: argparse.Namespace, terminated: list[int]) -> int:
    from .outputs import claim, describe_os_error

    try:
        with claim(args):  # the output rule (outputs.py), before any of the command's work
            return int(args.func(args) or 0)
    except BaseException as exc:  # noqa: BLE001 - sorted below; anything else is re-raised
        # a Ctrl-C may surface as another exception: a SystemError from a compiled (numba)
        # kernel, or Dr.Jit's NameError from an ImportError while its extension first loads
        if isinstance(exc, KeyboardInterrupt) or (isinstance(exc, Exception)
                                                  and caused_by_interrupt(exc)):
            # every finished sample and file is already on disk (written atomically)
            print(f"\ntactip {args.command}: interrupted; what was finished is kept, and "
                  "running the same command again continues from there", file=sys.stderr)
            return 143 if terminated else 130  # 128 + SIGTERM / SIGINT, as a shell reports it
        if isinstance(exc, SceneError):
            print(f"tactip: scene error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, OSError) and exc.filename is not None:
            print(f"tactip {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
            return 1
        if isinstance(exc, ValueError | RuntimeError | OSError):
            print(f"tactip {args.command}: error: {exc}", file=sys.stderr)
            return 1
        raise


@contextlib.contextmanager
def _held_interrupt() -> Iterator[list[int]]:
    """While the block runs, a Ctrl-C (SIGINT) is recorded instead of raised; the yielded
    list holds it afterwards. Python's own handler is restored after the block."""
    import signal
    import threading

    seen: list[int] = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield seen
        return
    signal.signal(signal.SIGINT, lambda signum, frame: seen.append(signum))
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[list[int]]:
    """While the command runs, SIGTERM (``kill``, ``timeout``, a batch system's stop)
    interrupts like Ctrl-C, so a terminated run also removes its temporary files and stops its
    child processes (Python's default for SIGTERM exits at once, skipping both). Yields a list
    that holds the signal once it arrived; the previous handler is restored after."""
    import signal
    import threading

    seen: list[int] = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield seen
        return

    def handler(signum: int, frame: object) -> None:
        seen.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
