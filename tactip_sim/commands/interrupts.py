"""What an interrupted run looks like, shared by the entry point (:mod:`.launch`) and the
command line (:mod:`.cli`). Imports nothing: the entry point loads it before it takes over
Ctrl-C."""

from __future__ import annotations


def caused_by_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a KeyboardInterrupt or was raised while handling one (its chain)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False
