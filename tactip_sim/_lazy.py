"""Public names imported on first use (PEP 562), for packages whose import must run nothing:
``tactip``'s entry point takes over Ctrl-C before any heavy import starts
(:mod:`tactip_sim.commands.launch`). Only ``importlib`` is imported here, which Python's
start-up has loaded already."""

from __future__ import annotations

from importlib import import_module


def lazy_attributes(package: str, names: dict[str, str], namespace: dict[str, object]
                    ) -> tuple:
    """``(__getattr__, __dir__)`` for ``package``: each of ``names`` (public name -> module,
    relative to ``package``) is imported when first read and kept in ``namespace`` (the
    package's ``globals()``)."""

    def __getattr__(name: str) -> object:
        if name in names:
            value = getattr(import_module(names[name], package), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(names))

    return __getattr__, __dir__
