"""Process settings for the Dask workers that run sweeps (local or on a remote cluster).

Kept apart from :mod:`tactip_lab.sampling.sweep` so that importing the sweep code does not import
``distributed``; :func:`tactip_lab.sampling.executor.open_client` registers the plugin on every
client it
opens, and Dask applies it to every worker, including those that join or restart later.
"""

from __future__ import annotations

import logging
from typing import Any

from distributed import WorkerPlugin

MMAP_THRESHOLD_BYTES = 32 << 20
"""Blocks below this come from the heap, not fresh ``mmap`` pages (glibc's largest setting)."""
TRIM_THRESHOLD_BYTES = 128 << 20
"""Free heap kept by the process before it is returned to the system."""


def steady_allocator() -> bool:
    """Let this process reuse freed heap memory for its per-frame arrays (glibc only).

    A sample allocates a few hundred frame-sized arrays (1-2 MB each). Dask's nanny starts
    every worker with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes glibc's adaptive
    ``mmap`` threshold at 128 kB: each of those arrays then costs an ``mmap``, page faults on
    fresh zeroed pages, and a ``munmap``, and a worker ran a sample 1.3-1.6x slower than the
    same code in a plain process (BENCHMARKS.md, "End to end"). Setting both thresholds
    restores heap reuse; :class:`SweepWorkerSetup` does it in every Dask worker, local or on
    a remote cluster. Memory stays flat: the sizes repeat from sample to sample.

    Returns whether the settings were applied (False off glibc)."""
    import ctypes
    import platform

    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # pragma: no cover - glibc without the usual soname
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(libc.mallopt(m_mmap_threshold, MMAP_THRESHOLD_BYTES)
                and libc.mallopt(m_trim_threshold, TRIM_THRESHOLD_BYTES))


#: Dask warnings that an interrupted sweep triggers and that say nothing the user needs:
#: logger name -> the message fragment that identifies them.
EXPECTED_ON_INTERRUPT = {
    # a worker, for each task running when the client cancelled the sweep
    "distributed.worker.state_machine": "ended with CancelledError",
    # the nanny (in the client's process), for a worker still in the middle of a sample
    "distributed.nanny": "Worker process still alive after",
}


class QuietInterrupt(logging.Filter):
    """Drops one logger's warnings listed in :data:`EXPECTED_ON_INTERRUPT`.

    An interrupted ``calibrate`` cancels the running tasks and closes the cluster while workers
    are mid-sample; Dask logs that, and printed before the one-line "interrupted; what was
    finished is kept" message those lines read like a failure."""

    def __init__(self, fragment: str) -> None:
        super().__init__()
        self.fragment = fragment

    def filter(self, record: logging.LogRecord) -> bool:
        return self.fragment not in record.getMessage()


def quiet_interrupt(logger_name: str) -> None:
    """Install :class:`QuietInterrupt` on one of the loggers of :data:`EXPECTED_ON_INTERRUPT`
    (once per process)."""
    log = logging.getLogger(logger_name)
    if not any(isinstance(f, QuietInterrupt) for f in log.filters):
        log.addFilter(QuietInterrupt(EXPECTED_ON_INTERRUPT[logger_name]))


def one_thread_pools() -> None:
    """One thread for the BLAS (OpenBLAS, the FEM's dense algebra) and Dr.Jit (Mitsuba's
    LLVM back end) pools of this process: a worker's parallelism is its task slot, and each
    pool otherwise starts a thread per core, so N workers on N cores run 2N busy threads."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    import drjit

    drjit.set_thread_count(1)


class SweepWorkerSetup(WorkerPlugin):
    """On each worker: heap reuse for the per-frame arrays
    (:func:`steady_allocator`), one OpenCV thread, and no warnings for tasks an interrupt
    cancelled (:class:`QuietInterrupt`).

    A worker's parallelism is its task slots (one per process in ``--workers N``). OpenCV's
    own thread pool on top of that puts two threads per core on this 2-core machine; with one
    OpenCV thread per worker, 2 workers perceived 6-10 % more frames per second
    (benchmarks/bench_calibration.py, BENCHMARKS.md). Serial runs keep OpenCV's default.
    """

    name = "tactip-sweep-setup"
    idempotent = True  # a second client registering it again does not re-run setup()

    def setup(self, worker: Any) -> None:
        import cv2

        steady_allocator()
        cv2.setNumThreads(1)
        one_thread_pools()
        quiet_interrupt("distributed.worker.state_machine")
