"""``tactip``'s entry point: the console script and ``python -m tactip_sim.commands`` call
:func:`main`, the first code of a ``tactip`` run.

A Ctrl-C may come at any moment of a run and must end it with one line and exit status 130,
never a traceback: while the modules load (0.5-3 s: numpy, scipy, trimesh, the subcommands),
while the command runs (:func:`tactip_sim.commands.cli.run` handles it there) and while Python
shuts down after the command. So this module imports only ``signal``, ``os``, ``sys``,
``atexit`` and :mod:`.interrupts` (which imports nothing), and the packages above it
(``tactip_sim``, ``tactip_sim.commands``) import nothing at their top: :func:`main` takes
over SIGINT ~2 ms after Python's own start-up ends. What comes before (the interpreter's
start-up and ``site``) runs no code of the tool; docs/robustness.md ("Ctrl-C at any moment of
a run") gives the measured widths.

:func:`main` changes the process's SIGINT handling for good (it owns the process): in-process
callers (tests, scripts) use :func:`tactip_sim.commands.main` instead.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys

from .interrupts import caused_by_interrupt

INTERRUPTED = 130
"""The exit status of an interrupted run: 128 + SIGINT, as a shell reports it."""


def main(argv: list[str] | None = None) -> int:
    """Run ``tactip`` with ``argv`` (default: ``sys.argv[1:]``) as the program; returns its exit
    status (see :func:`tactip_sim.commands.cli.main`; 130 if interrupted at any point)."""
    status = _main(argv)
    _RETURNED[:] = [status]
    return status


_RETURNED: list[int] = []
"""The status :func:`main` returned (for :func:`_quiet_end`)."""


def _main(argv: list[str] | None) -> int:
    held: list[int] = []
    owned = False
    try:
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            atexit.register(_quiet_end)  # registered first, so it runs after every other one
            # from here until the command starts, a Ctrl-C is recorded, not raised: some
            # libraries import their optional parts under `except BaseException` (trimesh),
            # which swallowed it, and an import cut short leaves half-loaded modules
            try:
                signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
                owned = True
            except ValueError:  # not the main thread: leave SIGINT alone
                pass
        if not owned:  # SIGINT ignored by whoever started us (nohup, `cmd &`), or a thread
            from .cli import main as run

            return run(argv)
        try:
            from . import cli

            parser = cli.build_parser()
        finally:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        if held:
            return _interrupted("before the command started")
        status = cli.run(parser, argv)
        if status in (INTERRUPTED, 143):
            _end_if_half_loaded(status)
        return status
    except KeyboardInterrupt:  # between the steps above, or a command without its own handling
        if not owned and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            owned = True  # the Ctrl-C came before the handler above was in place
        return _interrupted("", owned)
    except Exception as exc:
        # a Ctrl-C may surface as another exception caused by it: a SystemError from a
        # compiled kernel (numba), a NameError from Dr.Jit's first import (an ImportError
        # while its extension loads, whose handler names an unbound variable)
        if not caused_by_interrupt(exc):
            raise
        status = _interrupted("", owned)
        _end_if_half_loaded(status)
        return status
    finally:
        if owned:
            _guard_exit()




def _end_if_half_loaded(status: int) -> None:
    """After an interrupt, end the process at once (streams flushed, ``status`` kept) when
    Dr.Jit or Mitsuba was loading: a Ctrl-C while their binary extensions initialise leaves
    them half set up, and Python's finalisation then aborted the process ("Fatal Python
    error: PyThreadState_Get", SIGABRT, measured: 2 of 15 runs interrupted 0.25-0.27 s into
    Dr.Jit's extension). The command has returned: its files are complete."""
    if not any(m == "drjit" or m.startswith(("drjit.", "mitsuba")) for m in sys.modules):
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - interrupted mid-write: keep what was written
            pass
    os._exit(status)


def _interrupted(when: str, owned: bool = True) -> int:
    if owned:
        _guard_exit()  # a second Ctrl-C while this prints ends the process at once, quietly
    print(f"\ntactip: interrupted{' ' + when if when else ''}", file=sys.stderr)
    return INTERRUPTED


def _guard_exit() -> None:
    """From here to the process's end (Python joins threads and runs its exit handlers, which
    a library's may make slow), a Ctrl-C ends the process at once with one line and status 130:
    the command has returned, so every file it wrote is complete. Python's default handler
    would raise KeyboardInterrupt inside those exit handlers: a traceback."""
    if signal.getsignal(signal.SIGINT) is _stop_now:
        return
    try:
        signal.signal(signal.SIGINT, _stop_now)
    except ValueError:  # not the main thread
        pass
    except KeyboardInterrupt:
        # Python runs a pending Ctrl-C's handler before it changes the handler: that one
        _stop_now(signal.SIGINT, None)


def _stop_now(signum: int, frame: object) -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - interrupted mid-write: keep what was written
            pass
    try:
        os.write(2, b"\ntactip: interrupted while exiting (the command had ended)\n")
    finally:
        os._exit(INTERRUPTED)


def _quiet_end() -> None:
    """The last exit handler the tool registers (the first registered, so it runs after every
    exit handler registered after it). From here Python only flushes and frees, and the
    freeing took 0.65-0.8 s once Mitsuba and Dr.Jit were loaded (~1 900 modules, ~200 000
    objects: the garbage collector's passes while Python clears its modules, seen with gdb); a
    Ctrl-C there was ignored and the run exited 0 without a word (docs/robustness.md).

    So when :func:`main` is the program (the console script and ``python -m`` run
    ``sys.exit(main())``), the process ends right after the remaining exit handlers (those
    registered before the tool's first line, e.g. by a ``.pth`` file), in Python's flush of
    ``sys.stderr`` that follows them, with the status :func:`main` returned; until then a
    Ctrl-C ends it as one during the exit handlers does. Otherwise (an in-process caller)
    SIGINT is ignored for Python's last steps, so the run keeps its exit status (Python's own
    handler is gone by then: the signal would kill the process)."""
    if _RETURNED and _is_program() and sys.stderr is not None:
        sys.stderr = _EndInFinalFlush(sys.stderr, _RETURNED[0])
        return
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except KeyboardInterrupt:  # pending, run by the handler in place first
        _stop_now(signal.SIGINT, None)


def _is_program() -> bool:
    """Whether the process's exit status is the one :func:`main` returned: the script run as
    ``__main__`` (pip's console script, ``commands/__main__.py``) calls it as ``main``."""
    return getattr(sys.modules.get("__main__"), "main", None) is main


class _EndInFinalFlush:
    """``sys.stderr`` for the process's last steps: once every exit handler has run, Python
    flushes ``sys.stdout`` and ``sys.stderr`` (``Py_FinalizeEx``: after the exit handlers,
    before it removes its signal handlers and frees its modules); that flush of stderr ends
    the process with ``status``. Before it (``sys.is_finalizing()`` false) the stream is
    stderr as it was."""

    def __init__(self, stream: object, status: int) -> None:
        self._stream = stream
        self._status = status

    def __getattr__(self, name: str) -> object:
        return getattr(self._stream, name)

    def flush(self) -> None:
        if not sys.is_finalizing():
            self._stream.flush()
            return
        status = self._status
        for stream in (self._stream, sys.stdout):
            if stream is None:
                continue
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - as Python's exit: 120 if stdout cannot be flushed
                if stream is sys.stdout and status == 0:
                    status = 120
        os._exit(status)
