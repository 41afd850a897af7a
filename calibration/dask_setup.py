"""Process settings for the Dask workers that run sweeps (local or on a remote cluster).

Kept apart from :mod:`calibration.sweep` so that importing the sweep code does not import
``distributed``; :func:`calibration.sweep.open_client` registers the plugin on every client it
opens, and Dask applies it to every worker, including those that join or restart later.
"""

from __future__ import annotations

from typing import Any

from distributed import WorkerPlugin


class SweepWorkerSetup(WorkerPlugin):
    """On each worker: heap reuse for the per-frame arrays
    (:func:`calibration.sweep.steady_allocator`) and one OpenCV thread.

    A worker's parallelism is its task slots (one per process in ``--workers N``). OpenCV's
    own thread pool on top of that puts two threads per core on this 2-core machine; with one
    OpenCV thread per worker, 2 workers perceived 6-10 % more frames per second
    (benchmarks/bench_calibration.py, BENCHMARKS.md). Serial runs keep OpenCV's default.
    """

    name = "tactip-sweep-setup"
    idempotent = True  # a second client registering it again does not re-run setup()

    def setup(self, worker: Any) -> None:
        import cv2

        from .sweep import steady_allocator

        steady_allocator()
        cv2.setNumThreads(1)
