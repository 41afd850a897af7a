"""The commands floor: the ``tactip`` command line and the reports it writes.

The top layer of ``tactip_sim`` (scene -> geometry -> mesh -> fem -> optics -> render ->
simulator -> commands): it may import every layer below it and the package facade, and nothing
below imports it. It is the only place of ``tactip_sim`` that prints.

* :mod:`.launch`: the program's entry point (the console script, ``python -m``): Ctrl-C at
  any moment of a run ends it with one line; so this package imports nothing at its top
  (the names below load on first use);
* :mod:`.cli`: ``tactip`` itself (:func:`main`, :func:`build_parser`) and the ``scene``,
  ``mesh`` and ``cache`` commands;
* :mod:`.args`: the scene arguments shared by every scene-reading command (also used by the
  subcommands ``calibration`` and ``perception`` register);
* :mod:`.press`: ``tactip press``; :mod:`.render`: ``tactip render``;
* :mod:`.validate_lens`: ``tactip validate-lens`` with its charts and Markdown report.
"""

from tactip_sim._lazy import lazy_attributes

_LAZY = {
    "DEFAULT_SCENE": ".args",
    "add_scene_argument": ".args",
    "load_scene_args": ".args",
    "parse_overrides": ".args",
    "with_overrides": ".args",
    "build_parser": ".cli",
    "main": ".cli",
}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals())

__all__ = sorted(_LAZY)
