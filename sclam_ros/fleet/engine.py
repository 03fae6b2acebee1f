"""The Dask cluster the work runs on: an embedded LocalCluster by default, nothing to set up,
or an existing cluster's scheduler (``tcp://HOST:8786``) that runs the same tasks.

Workers are processes with one thread each: registration and the solver hold the GIL most of
the time, so threads would not run in parallel; a process per core does.
"""
from __future__ import annotations

import logging
import os
from contextlib import contextmanager

log = logging.getLogger("sclam")


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, dashboard: bool = True):
    """``with dask_client(...) as client:`` a connected distributed.Client.

    ``scheduler``: address of an existing cluster's scheduler; otherwise a LocalCluster of
    ``workers`` single-threaded worker processes (default: one per core) is started and
    torn down on exit. The dashboard address is logged so that progress can be watched.
    """
    from distributed import Client, LocalCluster

    # Worker processes must not each start BLAS thread pools as wide as the machine: with one
    # process per core they would oversubscribe it.
    env = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    # Our log lines and the progress bar are what the user reads; Dask's own INFO chatter
    # (worker start/stop, ports) is not.
    for name in ("distributed", "distributed.nanny", "distributed.scheduler", "distributed.worker",
                 "distributed.core", "distributed.http.proxy"):
        logging.getLogger(name).setLevel(logging.WARNING)
    if scheduler:
        client = Client(scheduler)
        cluster = None
    else:
        cluster = LocalCluster(
            n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
            dashboard_address=":0" if dashboard else None, env=env,
        )
        client = Client(cluster)
    try:
        if dashboard and client.dashboard_link:
            log.info("Dask dashboard: %s", client.dashboard_link)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
