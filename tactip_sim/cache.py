"""The on-disk cache for meshes, factorisations and compliance matrices.

Location: ``$TACTIP_CACHE_DIR`` if set, else ``.cache/tactip`` in the project checkout (git
ignores it), else ``~/.cache/tactip_sim``. ``tactip cache clear`` empties it. Every file is
written atomically (temporary file + rename), so an interrupted run never leaves a torn entry.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np


def cache_dir() -> Path:
    env = os.environ.get("TACTIP_CACHE_DIR")
    if env:
        return Path(env)
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file() and os.access(root, os.W_OK):
        return root / ".cache" / "tactip"
    return Path.home() / ".cache" / "tactip_sim"


def path_for(kind: str, key: str, suffix: str) -> Path:
    return cache_dir() / kind / f"{key}{suffix}"


def save_npz(path: Path, **arrays: np.ndarray) -> None:
    """Atomically write a compressed-free ``.npz``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def clear() -> tuple[Path, int]:
    """Delete the cache folder; returns it and the number of files removed."""
    d = cache_dir()
    n = sum(1 for p in d.rglob("*") if p.is_file()) if d.exists() else 0
    shutil.rmtree(d, ignore_errors=True)
    return d, n
