"""Wall time of a calibration across invocations, including interrupted ones.

A calibration that is killed and rerun continues where it stopped, so one invocation's clock
says little about what the whole protocol cost. :class:`RunLog` keeps one entry per invocation
in ``runs.json`` beside the datasets, rewritten (atomically) at most every ``flush_s`` seconds
while samples are being written, when the invocation ends (also by an exception or Ctrl-C) and
once more when it finishes: only a killed process (SIGKILL, power loss) loses up to
``flush_s`` of its record. :meth:`RunLog.summary` sums the entries for the manifest.

One writer at a time: a RunLog holds its folder's write lock
(:func:`tactip_sim.commands.outputs.hold`, the lock every command takes on its ``--out``)
from its creation to :meth:`RunLog.finish` (or the end of the process), so a second process
calibrating into the same folder is refused naming the first, through the API as through
``tactip calibrate`` (two runs on one folder left ``runs.json`` claiming 0 samples for a run
that computed 115).
"""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tactip_lab.sampling.dataset import atomic_write_text

__all__ = ["RunLog"]


class RunLog:
    """``runs.json`` in a calibration folder: one entry per invocation.

    Parameters
    ----------
    path : the log file
    frames : perceived frames per sample (for the frames/s summary)
    flush_s : seconds between rewrites while samples are being written (default 0: after
        every sample, so that even a SIGKILL, which no handler sees, loses no count)
    info : anything else to record with this invocation (workers, scheduler, ...)
    """

    def __init__(self, path: str | Path, frames: int, *, flush_s: float = 0.0,
                 **info: Any) -> None:
        import contextlib

        from tactip_sim.commands.outputs import hold

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = contextlib.ExitStack()
        self._lock.enter_context(hold(self.path.parent, "calibrate"))
        self.previous = self._load()
        self.flush_s = float(flush_s)
        self._t0 = time.perf_counter()
        self._flushed = self._t0
        self.entry: dict[str, Any] = {
            "started_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "seconds": 0.0, "samples_computed": 0, "frames_per_sample": int(frames),
            "finished": False, **info,
        }
        self._write()

    def _load(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        try:
            runs = json.loads(self.path.read_text())
        except (OSError, ValueError):  # a damaged log only loses the history of timings
            return []
        return [r for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []

    def flush(self) -> None:
        """Write this invocation's entry as it stands (e.g. on the way out of an error)."""
        self._write()

    def _write(self) -> None:
        self.entry["seconds"] = round(time.perf_counter() - self._t0, 3)
        atomic_write_text(self.path, json.dumps([*self.previous, self.entry], indent=2))
        self._flushed = time.perf_counter()

    def tick(self, _index: int | None = None) -> None:
        """One more sample written (usable as ``run_sweep``'s ``on_sample``)."""
        self.entry["samples_computed"] += 1
        if time.perf_counter() - self._flushed >= self.flush_s:
            self._write()

    def finish(self) -> None:
        self.entry["finished"] = True
        self._write()
        self._lock.close()  # the folder's write lock (taken in __init__)

    @property
    def runs(self) -> list[dict[str, Any]]:
        return [*self.previous, self.entry]

    def summary(self) -> dict[str, Any]:
        """Totals over every invocation so far: wall seconds, samples, perceived frames/s."""
        runs = self.runs
        seconds = sum(float(r.get("seconds", 0.0)) for r in runs)
        samples = sum(int(r.get("samples_computed", 0)) for r in runs)
        frames = sum(int(r.get("samples_computed", 0)) * int(r.get("frames_per_sample", 0))
                     for r in runs)
        return {
            "invocations": len(runs),
            "interrupted": sum(not r.get("finished", False) for r in runs[:-1]),
            "total_s": round(seconds, 3),
            "samples_computed": samples,
            "frames_per_s": frames / seconds if seconds > 0 else None,
        }
