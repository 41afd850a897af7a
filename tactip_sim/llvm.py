"""Find a libLLVM that Dr.Jit's LLVM backend can really use, without risking the process.

A bad libLLVM (Debian 12's LLVM 15/16) imports fine but aborts the whole interpreter at the
first render (``LLVM ERROR: Cannot select: fminimum``). So each candidate is tried in a child
process that renders a tiny Mitsuba scene; the first that works is exported as
``DRJIT_LIBLLVM_PATH`` before Mitsuba/Dr.Jit load in this process. The verdict is cached (keyed
by the library's path, size and mtime and the Dr.Jit version), so the probe costs ~1 s once.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from . import cache

FIX = (
    "install Debian's libllvm19 (`apt-get install -y libllvm19`, done by ./setup.sh) or point "
    "DRJIT_LIBLLVM_PATH at a working libLLVM (version 17-20), e.g. "
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
)

_PROBE = """
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct"},
    "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4}},
    "s": {"type": "sphere", "center": [0, 0, 3]}, "e": {"type": "constant"}})
img = mi.render(scene, spp=1)
assert float(mi.TensorXf(img).array[0]) > 0
print("LLVM_OK")
"""


class LLVMError(RuntimeError):
    """No usable libLLVM for Dr.Jit's LLVM backend; the message names the fix."""


def _candidates() -> list[str]:
    pats = [
        "/usr/lib/x86_64-linux-gnu/libLLVM.so.*",
        "/usr/lib/x86_64-linux-gnu/libLLVM-*.so*",
        "/usr/lib/llvm-*/lib/libLLVM*.so*",
        "/usr/lib64/libLLVM*.so*",
        "/usr/local/lib/libLLVM*.so*",
    ]
    found = {os.path.realpath(p) for pat in pats for p in glob.glob(pat)}

    def version(p: str) -> tuple[int, ...]:
        m = re.search(r"(\d+)(?:\.(\d+))?", Path(p).name.split("LLVM", 1)[-1])
        return tuple(int(g) for g in m.groups() if g) if m else (0,)

    return sorted(found, key=version, reverse=True)


def probe(path: str | None, *, timeout: float = 120.0) -> tuple[bool, str]:
    """Render a 4x4 scene in a child process with ``DRJIT_LIBLLVM_PATH=path`` (None = Dr.Jit's
    own search). Returns (works, diagnostic)."""
    env = dict(os.environ)
    env.pop("DRJIT_LIBLLVM_PATH", None)
    if path is not None:
        if not Path(path).is_file():
            return False, f"{path}: no such file"
        env["DRJIT_LIBLLVM_PATH"] = path
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                             text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return False, f"{path}: probe timed out after {timeout:g} s"
    if res.returncode == 0 and "LLVM_OK" in res.stdout:
        return True, "ok"
    tail = (res.stderr.strip().splitlines() or ["(no output)"])[0][:200]
    return False, f"{path or 'default search'}: exit {res.returncode}: {tail}"


def _stamp(path: str) -> str:
    try:
        with interrupts_held():
            import drjit

        ver = drjit.__version__
    except ImportError:  # pragma: no cover - drjit is a hard dependency
        ver = "?"
    st = Path(path).stat()
    return f"{path}|{st.st_size}|{int(st.st_mtime)}|{ver}"


def ensure_llvm() -> str:
    """Make sure Dr.Jit will load a working libLLVM; return its path.

    Must run before ``mitsuba``/``drjit`` are imported in this process.

    Raises
    ------
    LLVMError
        No working libLLVM; the message lists what was tried and names the fix.
    """
    if "drjit" in sys.modules and os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    cache.drjit_cache_dir()  # Dr.Jit's kernels under the tool's cache, not ~/.drjit
    record = cache.cache_dir() / "llvm.json"
    known: dict[str, bool] = {}
    if record.is_file():
        try:
            known = json.loads(record.read_text())
        except (OSError, ValueError):
            known = {}
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    candidates = [user] if user else _candidates()
    tried: list[str] = []
    for cand in candidates:
        if not Path(cand).is_file():
            tried.append(f"{cand}: no such file")
            continue
        stamp = _stamp(cand)
        ok = known.get(stamp)
        if ok is None:
            ok, why = probe(cand)
            known[stamp] = ok
            record.parent.mkdir(parents=True, exist_ok=True)
            tmp = record.with_suffix(".tmp")
            tmp.write_text(json.dumps(known, indent=1))
            os.replace(tmp, record)
        else:
            why = "cached verdict: " + ("ok" if ok else "fails")
        if ok:
            os.environ["DRJIT_LIBLLVM_PATH"] = cand
            return cand
        tried.append(f"{cand}: {why}")
    where = "DRJIT_LIBLLVM_PATH" if user else "the system library folders"
    raise LLVMError(
        f"no working libLLVM for Dr.Jit's LLVM backend in {where} (tried: "
        f"{'; '.join(tried) or 'nothing found'}). Fix: {FIX}"
    )


def import_mitsuba(variant: str = "llvm_ad_rgb"):
    """Import Mitsuba with a working libLLVM and set ``variant``; returns the module."""
    ensure_llvm()
    with interrupts_held():
        import mitsuba as mi

        if mi.variant() != variant:
            mi.set_variant(variant)
    return mi


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) or SIGTERM while the block runs, then act on it.

    Dr.Jit's and Mitsuba's binary extensions must not be interrupted while they initialise:
    a KeyboardInterrupt raised inside them left them half set up (a NameError from Dr.Jit's
    own error handler, a segmentation fault: measured with SIGINT 0-0.1 s after
    ``drjit.detail``, ``benchmarks/ctrl_c_drjit_import.py``). So the block's imports run to
    the end (~0.1-0.2 s here), with each Python-level handler replaced by one that records
    the signal; afterwards the handlers are restored and a recorded signal is given to its
    handler (Python's raises KeyboardInterrupt). Handlers that are not Python functions
    (``SIG_IGN``, ``SIG_DFL``) and calls outside the main thread are left alone."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    seen: list[int] = []
    previous: dict[int, object] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(sig)
        if callable(handler):
            previous[sig] = handler
            signal.signal(sig, lambda signum, frame: seen.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(seen):
            previous[sig](sig, None)
