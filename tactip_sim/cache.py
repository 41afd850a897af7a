"""The on-disk cache for meshes, compliance matrices and marker responses.

Location: ``$TACTIP_CACHE_DIR`` if set, else ``.cache/tactip`` in the project checkout (git
ignores it), else ``~/.cache/tactip_sim``.

Guarantees:

* **Only what the tool wrote is ever deleted.** The tool writes into its own kind folders
  (:data:`KINDS`) and ``llvm.json``, and tags the cache folder with a ``CACHEDIR.TAG`` (the
  standard tag backup tools skip). ``tactip cache clear`` removes the entries of those kinds
  (files named as the tool names them), the tag, and folders it leaves empty; any other file
  in the folder, and the folder itself if it still holds one, stays.
* **Dr.Jit's kernel cache lives here too** (``drjit/``, through ``DRJIT_CACHE_DIR``, unless
  the user set that variable), not in ``~/.drjit``; ``clear`` removes the files Dr.Jit names
  as its own there.
* **Every entry is written atomically** (temporary file + rename): an interrupted run never
  leaves a torn entry.
* **An entry is built once when processes race for it** (the test suite's workers, two
  commands): :func:`build_lock` holds an advisory lock (``flock``, on a ``KEY.npz.lock``
  file beside the entry, removed when the build is done) while a process looks the entry up
  and builds it; the others wait, then load what it wrote.
* **Nothing loaded is trusted blindly.** Each ``.npz`` entry carries the SHA-256 of its arrays;
  :func:`load_npz` checks it, the keys and that the floats are finite. A truncated, edited or
  corrupt entry is reported (:class:`CacheWarning`), removed, and rebuilt by the caller.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import warnings
import zipfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

KINDS = ("mesh", "compliance", "marker_response", "background", "raster_maps")
"""Sub-folders the tool writes entries into."""
DRJIT = "drjit"
"""Sub-folder given to Dr.Jit as its kernel cache (``DRJIT_CACHE_DIR``), instead of
``~/.drjit``: see :func:`drjit_cache_dir`."""
_DRJIT_ENTRY = re.compile(r"^([0-9a-f]+\.(llvm|cuda)\.v\d+\.bin(\.\w+)?|sweep\.stamp)$")
"""Names Dr.Jit 1.x gives its kernel cache files (``<hash>.llvm.v6.bin``, ``sweep.stamp``)."""
FILES = ("llvm.json", "outputs.json")  # outputs.json: the commands' register of their files
"""Files the tool writes at the top of the cache folder."""
TAG = "CACHEDIR.TAG"
TAG_TEXT = ("Signature: 8a477f597d28d172789f06886806bc55\n"
            "# This file is a cache directory tag created by tactip-sim.\n"
            "# For information about cache directory tags see https://bford.info/cachedir/\n")
DIGEST_KEY = "_sha256"
LOCK_SUFFIX = ".lock"
_ENTRY = re.compile(r"^[\w.+-]+\.npz(\w+\.tmp|\.lock)?$")
"""Names the tool gives entries: ``KEY.npz``; while one is written ``KEY.npzXXXX.tmp``, and
while one is built ``KEY.npz.lock`` (:func:`build_lock`)."""


class CacheWarning(UserWarning):
    """A cache entry was unusable (truncated, edited, non-finite) and will be rebuilt."""


def cache_dir() -> Path:
    env = os.environ.get("TACTIP_CACHE_DIR")
    if env:
        return Path(env)
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file() and os.access(root, os.W_OK):
        return root / ".cache" / "tactip"
    return Path.home() / ".cache" / "tactip_sim"


def drjit_cache_dir() -> Path | None:
    """Point Dr.Jit's kernel cache at ``<cache>/drjit`` (it is ``~/.drjit`` otherwise) by
    setting ``DRJIT_CACHE_DIR`` (read by Dr.Jit >= 1.x when its backend starts, so this must
    run before Mitsuba is imported). A ``DRJIT_CACHE_DIR`` the user set is kept. Returns the
    folder in use, or None (the cache folder cannot be created: Dr.Jit's default then)."""
    user = os.environ.get("DRJIT_CACHE_DIR")
    if user:
        return Path(user)
    folder = cache_dir() / DRJIT
    try:
        folder.mkdir(parents=True, exist_ok=True)
        _tag(folder.parent)
    except OSError:
        return None
    os.environ["DRJIT_CACHE_DIR"] = str(folder)
    return folder


def path_for(kind: str, key: str, suffix: str) -> Path:
    if kind not in KINDS:
        raise ValueError(f"kind={kind!r} is not a cache kind: one of {', '.join(KINDS)}")
    return cache_dir() / kind / f"{key}{suffix}"


def _tag(folder: Path) -> None:
    tag = folder / TAG
    if not tag.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tag.write_text(TAG_TEXT)


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(k.encode())
        h.update(str(a.dtype).encode())
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_npz(path: Path, **arrays: np.ndarray) -> None:
    """Atomically write an uncompressed ``.npz`` with the SHA-256 of its arrays."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _tag(path.parent.parent)
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays, **{DIGEST_KEY: np.array(_digest(arrays))})
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_npz(path: Path, keys: Sequence[str]) -> dict[str, np.ndarray] | None:
    """The arrays ``keys`` of cache entry ``path``, or None if there is no entry or it is
    unusable: unreadable or truncated, a key missing, its digest not matching its arrays, or
    a float array holding NaN or inf. An unusable entry is removed and a :class:`CacheWarning`
    says why (the caller rebuilds it)."""
    if not path.is_file():
        return None
    why = ""
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            missing = [k for k in (*keys, DIGEST_KEY) if k not in data.files]
            if missing:
                why = f"missing {', '.join(missing)}"
            else:
                arrays = {k: data[k] for k in data.files if k != DIGEST_KEY}
                stored = str(data[DIGEST_KEY])
                if _digest(arrays) != stored:
                    why = "its content does not match its digest (edited or corrupt)"
                elif any(a.dtype.kind in "fc" and not np.isfinite(a).all()
                         for a in arrays.values()):
                    why = "it holds NaN or inf"
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        why = f"unreadable ({type(exc).__name__}: {exc})"
    if why:
        warnings.warn(f"cache entry {path} is unusable: {why}; removing it and rebuilding",
                      CacheWarning, stacklevel=2)
        path.unlink(missing_ok=True)
        return None
    return {k: arrays[k] for k in keys}


@contextmanager
def build_lock(path: Path) -> Iterator[None]:
    """Hold the build lock of cache entry ``path`` (``path_for(...)``): look the entry up and,
    if it is missing, build and save it inside ``with build_lock(path):``. A second process
    entering for the same entry waits until the first leaves, then finds the entry written.
    The lock is advisory (``fcntl.flock`` on ``KEY.npz.lock``, released when the process
    ends, even killed) and only saves work: entries are written atomically, so where there is
    no ``flock`` (not POSIX) or the folder is read-only, this does nothing and a race costs a
    second build, never a wrong entry. The lock file is removed on leaving."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    lock = path.with_name(path.name + LOCK_SUFFIX)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        try:  # remove the file unless a later process already replaced it with its own
            if os.path.samestat(os.fstat(fd), os.stat(lock)):
                lock.unlink()
        except OSError:
            pass
        os.close(fd)  # releases the lock


def _ours(folder: Path) -> list[Path]:
    """The files in ``folder`` the tool wrote (its kinds' entries, its top-level files)."""
    out = [folder / f for f in (*FILES, TAG) if (folder / f).is_file()]
    for kind in KINDS:
        d = folder / kind
        if d.is_dir():
            out += [p for p in d.iterdir() if p.is_file() and _ENTRY.match(p.name)]
    d = folder / DRJIT
    if d.is_dir():
        out += [p for p in d.iterdir() if p.is_file() and _DRJIT_ENTRY.match(p.name)]
    return out


def entries() -> list[Path]:
    """Every file of the cache the tool wrote."""
    d = cache_dir()
    return _ours(d) if d.is_dir() else []


def clear() -> tuple[Path, int]:
    """Delete the cache's entries (only files the tool wrote; see the module's guarantees).
    Returns the cache folder and the number of files removed."""
    d = cache_dir()
    files = entries()
    for p in files:
        p.unlink(missing_ok=True)
    for kind in (*KINDS, DRJIT):
        try:
            (d / kind).rmdir()  # only if now empty
        except OSError:
            pass
    try:
        d.rmdir()
    except OSError:
        pass
    return d, len(files)
