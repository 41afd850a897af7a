"""The commands floor: the ``tactip`` command line and the reports it writes.

The top layer of ``tactip_sim`` (scene -> geometry -> mesh -> fem -> optics -> render ->
simulator -> commands): it may import every layer below it and the package facade, and nothing
below imports it. It is the only place of ``tactip_sim`` that prints.

* :mod:`.cli`: ``tactip`` itself (:func:`main`, :func:`build_parser`) and the ``scene``,
  ``mesh`` and ``cache`` commands;
* :mod:`.args`: the scene arguments shared by every scene-reading command (also used by the
  subcommands ``calibration`` and ``perception`` register);
* :mod:`.press`: ``tactip press``; :mod:`.render`: ``tactip render``;
* :mod:`.validate_lens`: ``tactip validate-lens`` with its charts and Markdown report.
"""

from .args import (
    DEFAULT_SCENE,
    add_scene_argument,
    load_scene_args,
    parse_overrides,
    with_overrides,
)
from .cli import build_parser, main

__all__ = [
    "DEFAULT_SCENE",
    "add_scene_argument",
    "build_parser",
    "load_scene_args",
    "main",
    "parse_overrides",
    "with_overrides",
]
