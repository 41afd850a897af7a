"""A running clock for long steps that report nothing themselves (pytetwild's mesh, the
compliance precompute): shown on a terminal only, so logs and pipes stay clean."""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Iterator
from typing import IO


@contextlib.contextmanager
def clock(label: str, *, every_s: float = 1.0, file: IO[str] | None = None) -> Iterator[None]:
    """While the block runs, show ``label: <elapsed>`` on ``file`` (default stderr), refreshed
    every ``every_s`` seconds, if ``file`` is a terminal; the line is removed after."""
    from tqdm import tqdm

    bar = tqdm(desc=label, bar_format="{desc}: {elapsed}", disable=None, leave=False,
               file=file if file is not None else sys.stderr, mininterval=0)
    if bar.disable:
        yield
        return
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(every_s):
            bar.refresh()

    thread = threading.Thread(target=tick, name="tactip-clock", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        bar.close()
