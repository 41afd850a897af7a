"""The output rule of every ``tactip`` command, in one place (issue 54).

A command declares, where it registers its parser (:func:`declare`), which of its arguments
name what it reads (scene files, images, model files, labelled folders...) and what it writes
(output files, output folders). :func:`tactip_sim.commands.cli.run` applies the rule through
:func:`claim` before the command's own code runs, so a refusal costs milliseconds:

* **Inputs are never outputs.** An output is refused when it is one of the command's inputs,
  lies inside an input folder, or (an output folder) holds an input. Two outputs of one run
  may not name the same path, and one input may not be given twice.
* **What is read is what it claims to be.** A missing input, a folder where a file is read (or
  the reverse), a FIFO, a device (``/dev/zero``), an unreadable file, a TOML file with a
  byte-order mark or that is not UTF-8 text: each refused naming the option and the file.
* **No user file is replaced** without ``--overwrite``. An output file that exists is refused,
  unless it is the tool's own: a file a command wrote there and nobody changed since (the
  register :data:`REGISTER` in the cache folder keeps the size, time and SHA-256 of every
  output file a command finished), a file the command recognises (``fit`` replaces a model
  file), or a file inside an output folder of the same command.
* **Output folders carry a marker** (:data:`MARKER`, the command that made them). A folder
  made by another command is refused; a folder without a marker that holds anything is
  refused (a user's folder: its same-named files would be replaced), unless it is recognisably
  the command's own from before markers existed (``legacy``) or ``--overwrite`` is given.
  A file is never written inside a folder another command made.
* **One writer per output folder.** :func:`hold` takes an exclusive lock (``flock``) on the
  folder itself for the run and records the writer (command, process id, host, start) in the
  marker; a second writer is refused naming it. The lock dies with its process (also on
  SIGKILL): no lock file, nothing stale to clear. (``flock`` may not lock across machines on
  some network file systems.)
* The parents of every output are checked up front: a missing folder is created, a file in
  the way, or a folder the user may not write in, is named before any work.

A folder the run created and left holding only the marker (a refusal later in the command,
Ctrl-C before the first file) is removed again.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import socket
import stat
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

MARKER = ".tactip-output.json"
"""In every output folder: ``{"tool": "tactip", "command": ..., "created_utc": ...,
"writer": {the last run that held the lock}}``."""
REGISTER = "outputs.json"
"""In the cache folder (:func:`tactip_sim.cache.cache_dir`): path -> size, mtime and SHA-256
of the output files commands wrote (the newest :data:`REGISTER_SIZE`)."""
REGISTER_SIZE = 2000
OWN_FILES = (MARKER,)
"""The files of the rule itself: a folder holding only these is empty for every other use."""

INPUT_KINDS = ("file", "folder", "path", "toml", "file-or-name")
"""``file``: a regular file; ``folder``; ``path``: either; ``toml``: a UTF-8 TOML file;
``file-or-name``: a file, or a name the command resolves (a preset) when no such path exists."""


class OutputError(ValueError):
    """An input or output path the rule refuses (the message names the option and the file)."""


@dataclass(frozen=True)
class Spec:
    """What a command reads and writes: argument ``dest`` -> kind (:data:`INPUT_KINDS`) for
    inputs; the ``dest`` of output files and output folders. ``own``: ``dest`` -> a test that an
    existing file is the command's own output (it may be replaced); ``legacy``: a test that a
    folder without a marker was made by an earlier version of the command; ``stdout``: output
    files for which ``-`` means standard output; ``siblings``: ``dest`` -> the suffixes of the
    files written beside it (``render -o x.png`` also writes ``x.json``, ``x.csv``)."""

    command: str
    inputs: dict[str, str] = field(default_factory=dict)
    files: tuple[str, ...] = ()
    folders: tuple[str, ...] = ()
    names: dict[str, str] = field(default_factory=dict)
    own: dict[str, Callable[[Path], bool]] = field(default_factory=dict)
    legacy: Callable[[Path], bool] | None = None
    stdout: tuple[str, ...] = ()
    siblings: dict[str, tuple[str, ...]] = field(default_factory=dict)
    mark: bool = True
    """False: the folders get no marker (a folder format that refuses any file it did not
    write, e.g. a sweep's dataset, which has its own manifest); they are still locked."""


def declare(parser: argparse.ArgumentParser, command: str, *,
            inputs: dict[str, str] | None = None, files: Sequence[str] = (),
            folders: Sequence[str] = (), own: dict[str, Callable[[Path], bool]] | None = None,
            legacy: Callable[[Path], bool] | None = None, stdout: Sequence[str] = (),
            siblings: dict[str, tuple[str, ...]] | None = None, overwrite: bool = True,
            mark: bool = True) -> Spec:
    """Declare ``parser``'s inputs and outputs (argument ``dest`` names, as the parser has
    them) and add ``--overwrite`` (unless ``overwrite=False``). Returns the :class:`Spec`, which
    :func:`claim` applies before the command runs."""
    inputs = dict(inputs or {})
    for kind in inputs.values():
        if kind not in INPUT_KINDS:
            raise ValueError(f"input kind {kind!r} is not one of {INPUT_KINDS}")
    names = {}
    by_dest = {a.dest: a for a in parser._actions}
    for dest in (*inputs, *files, *folders):
        action = by_dest.get(dest)
        if action is None:
            raise ValueError(f"{command}: no argument {dest!r} to declare")
        names[dest] = (max(action.option_strings, key=len) if action.option_strings
                       else (action.metavar if isinstance(action.metavar, str)
                             else dest.upper()))
    if overwrite and (files or folders) and "overwrite" not in by_dest:
        parser.add_argument("--overwrite", action="store_true",
                            help="replace existing files that this command did not make "
                            "(never its own inputs)")
    spec = Spec(command, inputs, tuple(files), tuple(folders), names, dict(own or {}), legacy,
                tuple(stdout), dict(siblings or {}), mark)
    parser.set_defaults(_outputs=spec)
    return spec


# --- inputs ------------------------------------------------------------------------------

def _what(mode: int) -> str | None:
    """What a non-regular, non-folder file is, or None."""
    for test, name in ((stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return None


def check_input(path: str | os.PathLike[str], name: str, kind: str = "path") -> Path | None:
    """``path`` resolved, after checking it is an input of ``kind`` (:data:`INPUT_KINDS`); None
    for a ``file-or-name`` that is a name.

    Raises
    ------
    OutputError
        Naming ``name`` (the option), the path and what it is instead.
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        if kind == "file-or-name" and os.sep not in str(path) and not p.suffix:
            return None
        raise OutputError(f"{name} {str(path)!r}: no such "
                          f"{'folder' if kind == 'folder' else 'file'}") from None
    except NotADirectoryError:
        raise OutputError(f"{name} {str(path)!r}: a part of the path is a file, not a "
                          "folder") from None
    except PermissionError:
        raise OutputError(f"{name} {str(path)!r}: permission denied (a folder on the way may "
                          "not be entered)") from None
    odd = _what(st.st_mode)
    want = {"folder": "a folder", "path": "a file or a folder"}.get(kind, "a file")
    if odd is not None:
        raise OutputError(f"{name} {str(path)!r} is {odd}, not a regular file: give {want} "
                          "(a stream is not read)")
    is_dir = stat.S_ISDIR(st.st_mode)
    if kind == "folder" and not is_dir:
        raise OutputError(f"{name} {str(path)!r} is a file: give a folder")
    if kind in ("file", "toml", "file-or-name") and is_dir:
        raise OutputError(f"{name} {str(path)!r} is a folder: give a file")
    if not os.access(p, os.R_OK | (os.X_OK if is_dir else 0)):
        raise OutputError(f"{name} {str(path)!r}: permission denied (not readable by this "
                          "user)")
    if kind == "toml" or (kind == "file-or-name" and p.suffix.lower() == ".toml"):
        head = p.read_bytes()[: 1 << 20]
        if head.startswith(b"\xef\xbb\xbf"):
            raise OutputError(f"{name} {str(path)!r} starts with a UTF-8 byte-order mark "
                              "(some Windows editors add one), which TOML does not allow: "
                              "save the file as UTF-8 without BOM")
        try:
            head.decode("utf-8")
        except UnicodeDecodeError as exc:
            if exc.start < len(head) - 4:  # not just a character cut by the 1 MiB read
                raise OutputError(f"{name} {str(path)!r} is not a text (TOML) file: byte "
                                  f"{exc.start} is not UTF-8 (an image or a binary "
                                  "file?)") from None
    return p.resolve()


# --- outputs -----------------------------------------------------------------------------

def marker_of(folder: Path) -> dict[str, Any] | None:
    """The marker of ``folder`` (None if it has none; ``{}`` if it is unreadable)."""
    m = folder / MARKER
    if not m.is_file():
        return None
    try:
        data = json.loads(m.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def manifest_kind(folder: Path) -> str | None:
    """The ``kind`` of ``folder``'s ``manifest.json`` (how an output folder of a command made
    before folders were marked is recognised: ``legacy``), or None."""
    try:
        data = json.loads((Path(folder) / "manifest.json").read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return data.get("kind") if isinstance(data, dict) else None


def _marked_ancestor(path: Path) -> tuple[Path, str] | None:
    for d in path.parents:
        m = marker_of(d)
        if m is not None:
            return d, str(m.get("command", "?"))
    return None


def _check_parent(path: Path, name: str) -> None:
    """The folder ``path`` would be written in: it exists (or can be made) and is writable."""
    d = path.parent
    while not d.exists():
        if d.is_symlink():
            raise OutputError(f"{name} {str(path)!r}: {str(d)!r} is a broken link")
        d = d.parent
    if not d.is_dir():
        raise OutputError(f"{name} {str(path)!r}: {str(d)!r} is a file, not a folder")
    if not os.access(d, os.W_OK | os.X_OK):
        raise OutputError(f"{name} {str(path)!r}: this user may not write in {str(d)!r} "
                          "(permission denied): choose another place")


def _same_file(a: Path, b: Path) -> bool:
    """``a`` and ``b`` are one file (a hard link is another path to the same data)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _relation(out: Path, inputs: list[tuple[str, Path]]) -> str | None:
    for name, p in inputs:
        if out == p or _same_file(out, p):
            return f"is {name} {str(p)!r}, which the command reads"
        if p in out.parents and p.is_dir():
            return f"lies inside {name} {str(p)!r}, which the command reads"
    return None


def check_output_file(path: Path, name: str, inputs: list[tuple[str, Path]], *,
                      command: str, overwrite: bool = False,
                      own: Callable[[Path], bool] | None = None) -> Path:
    """``path`` resolved, after the rule's checks for an output file (module docstring)."""
    out = path.resolve()
    why = _relation(out, inputs)
    if why:
        raise OutputError(f"{name} {str(path)!r} {why}: a command never writes over its own "
                          "inputs; choose another path")
    marked = _marked_ancestor(out)
    if marked is not None and marked[1] != command:
        raise OutputError(f"{name} {str(path)!r} lies inside {str(marked[0])!r}, an output "
                          f"folder of tactip {marked[1]}: choose a path outside it")
    if path.is_symlink() or path.exists():
        try:
            st = path.stat()
        except OSError:
            st = None
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise OutputError(f"{name} {str(path)!r} is a folder: give a file name")
        if st is not None and _what(st.st_mode):
            raise OutputError(f"{name} {str(path)!r} is {_what(st.st_mode)}: give a regular "
                              "file's path")
        ours = (marked is not None or (own is not None and own(path))
                or _registered(out))
        if not overwrite and not ours:
            what = (f"is not {own.what}" if hasattr(own, "what")
                    else "was not written by tactip (or was changed since)")
            raise OutputError(f"{name} {str(path)!r} exists and {what}: refusing to replace "
                              "it (give --overwrite to replace it, or another path)")
        if not os.access(path, os.W_OK) and not os.access(path.parent, os.W_OK):
            raise OutputError(f"{name} {str(path)!r}: permission denied")
    _check_parent(path, name)
    return out


def check_output_folder(path: Path, name: str, inputs: list[tuple[str, Path]], *,
                        command: str, overwrite: bool = False,
                        legacy: Callable[[Path], bool] | None = None) -> Path:
    """``path`` resolved, after the rule's checks for an output folder (module docstring)."""
    out = path.resolve()
    why = _relation(out, inputs)
    if why:
        raise OutputError(f"{name} {str(path)!r} {why}: a command never writes into its own "
                          "inputs; choose another folder")
    for iname, p in inputs:
        if out in p.parents:
            raise OutputError(f"{name} {str(path)!r} holds {iname} {str(p)!r}: the command "
                              "owns its output folder and never writes where its inputs are; "
                              "choose another folder")
    marked = _marked_ancestor(out)
    if marked is not None and marked[1] != command:
        raise OutputError(f"{name} {str(path)!r} lies inside {str(marked[0])!r}, an output "
                          f"folder of tactip {marked[1]}: choose a folder outside it")
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise OutputError(f"{name} {str(path)!r} exists and is not a folder")
        m = marker_of(path)
        if m is not None:
            made = str(m.get("command", "?"))
            if made != command:
                raise OutputError(f"{name} {str(path)!r} was made by tactip {made}, not by "
                                  f"tactip {command}: choose another folder")
        else:
            theirs = sorted(p.name for p in path.iterdir() if p.name not in OWN_FILES)
            if theirs and not overwrite and not (legacy is not None and legacy(path)):
                shown = ", ".join(theirs[:4]) + (f" and {len(theirs) - 4} more"
                                                 if len(theirs) > 4 else "")
                raise OutputError(
                    f"{name} {str(path)!r} holds files tactip {command} did not make ({shown}), "
                    "which it could replace: choose a new or empty folder (or give "
                    "--overwrite to write into it)")
        if not os.access(path, os.W_OK | os.X_OK):
            raise OutputError(f"{name} {str(path)!r}: this user may not write in it "
                              "(permission denied): choose another folder")
    else:
        _check_parent(path, name)
    return out


# --- the register of files the tool wrote -------------------------------------------------

def _register_path() -> Path:
    from tactip_sim import cache

    return cache.cache_dir() / REGISTER


def _fingerprint(path: Path) -> list[Any] | None:
    import hashlib

    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):
            return None
        h = hashlib.sha256()
        with path.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns, h.hexdigest()]


def _read_register() -> dict[str, Any]:
    try:
        data = json.loads(_register_path().read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def _registered(path: Path) -> bool:
    """Whether ``path`` is a file a command wrote there, unchanged since."""
    entry = _read_register().get(str(path))
    return entry is not None and entry == _fingerprint(path)


def register_outputs(paths: Sequence[Path]) -> None:
    """Record ``paths`` (written by a command that finished) in the register. A register that
    cannot be written only costs the next run an ``--overwrite``."""
    import tempfile

    data = _read_register()
    for p in paths:
        fp = _fingerprint(p)
        if fp is not None:
            data.pop(str(p), None)
            data[str(p)] = fp
    data = dict(list(data.items())[-REGISTER_SIZE:])
    target = _register_path()
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{REGISTER}.", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(data))
        os.replace(tmp, target)
    except OSError:
        with contextlib.suppress(OSError, UnboundLocalError):
            Path(tmp).unlink(missing_ok=True)


# --- the lock ----------------------------------------------------------------------------

_HELD: dict[Path, list[int]] = {}
"""Folders this process holds the lock of: resolved path -> [fd, count] (re-entrant)."""


class BusyError(OutputError):
    """Another process writes into the folder (its details in the message)."""


@contextlib.contextmanager
def hold(folder: str | os.PathLike[str], command: str) -> Iterator[None]:
    """Hold ``folder``'s write lock while the block runs (the folder must exist); a marked
    folder records the writer in its marker. Re-entrant within one process.

    Raises
    ------
    BusyError
        Another process holds it: the message names its command, process id, host and start
        (as its marker recorded them).
    """
    import fcntl

    key = Path(folder).resolve()
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield
        finally:
            _release(key)
        return
    fd = os.open(key, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        w = (marker_of(key) or {}).get("writer")
        who = (f"tactip {w.get('command')}, process {w.get('pid')} on {w.get('host')}, "
               f"started {w.get('started_utc')}") if isinstance(w, dict) else "another process"
        raise BusyError(f"{str(folder)!r} is being written by another run ({who}): two writers "
                        "would mix their files; wait for it to end, or choose another "
                        "folder") from None
    except OSError:  # a file system without locks (ENOLCK, EOPNOTSUPP): write unlocked
        pass
    _HELD[key] = [fd, 1]
    try:
        m = marker_of(key)
        if m is not None:
            write_marker(key, str(m.get("command", command)), created=m.get("created_utc"),
                         writer={"command": command, "pid": os.getpid(),
                                 "host": socket.gethostname(), "started_utc": _now()})
        yield
    finally:
        _release(key)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _release(key: Path) -> None:
    import fcntl

    entry = _HELD[key]
    entry[1] -= 1
    if entry[1] == 0:
        del _HELD[key]
        with contextlib.suppress(OSError):
            fcntl.flock(entry[0], fcntl.LOCK_UN)
        os.close(entry[0])


# --- applying the rule -------------------------------------------------------------------

def _values(value: Any) -> list[Any]:
    if value is None:
        return []
    return list(value) if isinstance(value, list | tuple) else [value]


@contextlib.contextmanager
def claim(args: argparse.Namespace) -> Iterator[None]:
    """Apply the rule of ``args``' command (declared with :func:`declare`, or given as the
    plain dict ``_io`` of :class:`Spec`'s fields by a package that may not import this one)
    before it runs:
    check its inputs and outputs, create and mark its output folders and hold their locks
    while the block runs. A command that declared nothing passes through."""
    spec: Spec | None = getattr(args, "_outputs", None)
    if spec is None and isinstance(getattr(args, "_io", None), dict):
        spec = Spec(**args._io)  # a package that may not import this one (perception)
    if spec is None:
        yield
        return
    overwrite = bool(getattr(args, "overwrite", False))
    inputs: list[tuple[str, Path]] = []
    for dest, kind in spec.inputs.items():
        name = spec.names[dest]
        seen: dict[Path, str] = {}
        for v in _values(getattr(args, dest, None)):
            p = check_input(v, name, kind)
            if p is None:
                continue
            if p in seen:
                again = "" if seen[p] == str(v) else f" (also as {seen[p]!r})"
                raise OutputError(f"{name}: {str(v)!r} is given twice{again}: each input is "
                                  "read once, so give it once")
            seen[p] = str(v)
            inputs.append((name, p))
    outs: dict[Path, str] = {}

    def unique(p: Path, name: str, given: Any) -> None:
        if p in outs:
            raise OutputError(f"{name} {str(given)!r} and {outs[p]} name the same path: each "
                              "output needs its own")
        outs[p] = name

    written: list[Path] = []
    for dest in spec.files:
        for v in _values(getattr(args, dest, None)):
            if dest in spec.stdout and str(v) == "-":
                continue
            name = spec.names[dest]
            paths = [Path(v)] + [Path(v).with_suffix(s) for s in spec.siblings.get(dest, ())]
            for p in paths:
                written.append(check_output_file(p, name, inputs, command=spec.command,
                                                 overwrite=overwrite, own=spec.own.get(dest)))
                unique(written[-1], name, p)
    folders: list[Path] = []
    for dest in spec.folders:
        for v in _values(getattr(args, dest, None)):
            name = spec.names[dest]
            p = check_output_folder(Path(v), name, inputs, command=spec.command,
                                    overwrite=overwrite, legacy=spec.legacy)
            unique(p, name, v)
            folders.append(p)
    with contextlib.ExitStack() as stack:
        for d in folders:
            created = not d.exists()
            d.mkdir(parents=True, exist_ok=True)
            stack.callback(_tidy, d, created)
            if spec.mark and marker_of(d) is None:
                write_marker(d, spec.command)
            stack.enter_context(hold(d, spec.command))
        yield
    if written:
        register_outputs(written)


def write_marker(folder: Path, command: str, *, created: str | None = None,
                 writer: dict[str, Any] | None = None) -> None:
    """Mark ``folder`` as made by ``tactip command`` (written atomically), with the run that
    writes it now (``writer``, recorded by :func:`hold`)."""
    import tempfile

    data: dict[str, Any] = {"tool": "tactip", "command": command,
                            "created_utc": created or _now()}
    if writer is not None:
        data["writer"] = writer
    text = json.dumps(data) + "\n"
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tactip-marker.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, folder / MARKER)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _tidy(folder: Path, created: bool) -> None:
    """Remove ``folder`` if this run created it and it holds nothing but the rule's files."""
    if not created or not folder.is_dir():
        return
    try:
        rest = [p for p in folder.iterdir() if p.name not in OWN_FILES]
        if rest:
            return
        for f in OWN_FILES:
            (folder / f).unlink(missing_ok=True)
        folder.rmdir()
    except OSError:
        pass


# --- messages ----------------------------------------------------------------------------

_TMP = re.compile(r"^\.(?P<name>.+)\.[^./]+\.tmp$")
"""An atomic write's temporary file (``.NAME.XXXXXXXX.tmp``, :func:`atomic_write_bytes`)."""
_ADVICE = {
    13: "permission denied: this user may not write there; choose another place",
    17: "it already exists",
    20: "a part of the path is a file, not a folder",
    21: "it is a folder, not a file",
    28: "the disk is full",
    30: "the file system is read-only; choose another place",
    36: "a name in the path is too long",
}


def describe_os_error(exc: OSError) -> str:
    """A one-line message for an :class:`OSError`: the file the user named (not an atomic
    write's hidden temporary file), what is wrong and what to do."""
    target = exc.filename
    if target is not None:
        p = Path(os.fsdecode(target))
        m = _TMP.match(p.name)
        if m:
            p = p.with_name(m.group("name"))
        target = str(p)
    what = _ADVICE.get(exc.errno or -1, exc.strerror or str(exc))
    if target is None:
        return f"{exc.strerror or exc}" if exc.errno in _ADVICE else str(exc)
    return f"cannot write or read {target!r}: {what}"


__all__ = ["MARKER", "OWN_FILES", "BusyError", "OutputError", "Spec", "check_input",
           "check_output_file", "check_output_folder", "claim", "declare", "describe_os_error",
           "hold", "manifest_kind", "marker_of", "write_marker"]
