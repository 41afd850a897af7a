"""Where samples are computed: in this process, on local worker processes or on a Dask cluster.

The executor knows nothing of what a sample is: it sends ``fn(spec, chunk)`` tasks out and
yields their results as they complete. ``--workers N`` starts a Dask ``LocalCluster`` of N
single-threaded processes; ``--scheduler ADDRESS`` uses any running Dask scheduler (other
machines included). A remote cluster's results come back to the client, so its workers need
no shared filesystem; a local cluster's workers write their files themselves
(:func:`tactip_lab.sampling.sweep.run_chunk`). Every worker, local or remote, gets
:class:`~tactip_lab.sampling.dask_setup.SweepWorkerSetup` (one OpenCV thread, glibc heap reuse).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

QUIET_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}
"""Dask settings of the local clusters :func:`open_client` starts. By default every worker
samples its task thread's stack every 10 ms (the dashboard's profile), its event loop wakes
every 20 ms to time itself, and it polls its resources every 0.5 s and its memory every 0.1 s.
Each wake-up takes the GIL from the sample being computed; the processes of a cluster also
share the machine's cores with the client and the scheduler. Slower diagnostics, same work:
2 workers on 2 cores went from 1.67-1.83x one worker to 1.90-1.99x (BENCHMARKS.md,
"Scaling"). Memory limits are still enforced, at most 1 s late. For a cluster started by
hand (``--scheduler``), the same keys can be set in its Dask configuration."""


def open_client(workers: int, scheduler: str | None, *, cluster_of_one: bool = False):
    """A Dask client: on ``scheduler`` if given, else on a LocalCluster of ``workers``
    single-threaded processes; None for in-process work (``workers <= 1``, no scheduler,
    unless ``cluster_of_one``: a benchmark's one-process cluster). Close it with
    :func:`close_client`."""
    if scheduler is None and workers <= 1 and not cluster_of_one:
        return None
    from dask.distributed import Client, LocalCluster

    from tactip_lab.sampling.dask_setup import SweepWorkerSetup, quiet_interrupt

    if scheduler is not None:
        client = Client(scheduler)
    else:
        import dask

        quiet_interrupt("distributed.nanny")  # the local nannies run in this process
        with dask.config.set(QUIET_WORKERS):  # the nannies hand it to their workers
            client = Client(LocalCluster(n_workers=workers, threads_per_worker=1,
                                         processes=True, dashboard_address=":0"))  # any port
    client.register_plugin(SweepWorkerSetup())  # also on workers that join or restart later
    return client


def close_client(client: Any) -> None:
    """Close a client of :func:`open_client` and the local cluster it started (if any)."""
    if client is None:
        return
    cluster = client.cluster
    client.close()
    if cluster is not None:
        cluster.close()


def execute(fn: Callable[[Any, list[int]], Any], spec: Any, chunks: Sequence[list[int]], *,
            workers: int = 1, scheduler: str | None = None, client: Any = None
            ) -> Iterator[Any]:
    """Yield ``fn(spec, chunk)`` for every chunk as it completes: in order in this process
    (``workers <= 1``, no scheduler, no client), else from Dask.

    client : an open client to use and leave open (e.g. one shared by all the sweeps of a
        calibration); without one, a client is opened for these chunks and closed after.
    """
    if not chunks:
        return
    own = client is None
    if own:
        client = open_client(workers, scheduler)
    if client is None:
        for c in chunks:
            yield fn(spec, c)
        return
    from dask.distributed import as_completed

    try:
        spec_f = client.scatter(spec, broadcast=True)
        futures = [client.submit(fn, spec_f, c, pure=False) for c in chunks]
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        if own:
            close_client(client)


def progress(total: int, initial: int, enabled: bool, desc: str):
    """A tqdm progress bar of samples (rate and ETA)."""
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, desc=desc, unit="sample",
                dynamic_ncols=True, smoothing=0.1)


__all__ = ["QUIET_WORKERS", "close_client", "execute", "open_client", "progress"]
