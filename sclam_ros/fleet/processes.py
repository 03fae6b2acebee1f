"""One recording's time chunks (chunked.py) registered on a pool of local processes.

Dask runs many recordings, or chunks on a cluster that is already up (`sclam fleet`,
`--scheduler`). For the chunks of one recording on this machine its LocalCluster costs more
to start (a scheduler, nanny and worker processes, each importing the package: seconds)
than the registration of a few minutes of data saves; forked processes start in
milliseconds with the package already imported (docs/decisions/parallel.md). Where fork is
not available the workers are spawned and import the package themselves. With fork the
pool starts every worker before its own manager thread: no thread is forked.

Workers are processes, one chunk each, for the reason engine.py gives (the registration
holds the interpreter lock). Each one writes how far it has read into shared memory, so the
progress bar moves while the chunks run.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import sys
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from sclam_ros.fleet.chunked import plan_for, recording_of, register_chunk

log = logging.getLogger("sclam")

_PROGRESS_SECONDS = 0.25  # how often the parent looks at the workers' progress
_shared = None  # in a worker: (fraction read, process id) of each chunk (shared arrays)


def _context():
    """fork where the platform has it and it is safe (Linux): the workers start with the
    parent's imports; else spawn."""
    if sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


def _init_worker(progress, pids) -> None:
    global _shared
    _shared = progress, pids


def _register(path, params, chunk):
    """register_chunk with its progress written to the shared array (a worker's task)."""
    progress, pids = _shared
    pids[chunk.number] = os.getpid()

    def report(done, total):
        progress[chunk.number] = min(1.0, done / total) if total else 1.0

    return register_chunk(path, params, chunk, progress=report)


def _stop(futures, pids) -> None:
    """Cancel the chunks not started and end the processes of those that are: interrupted,
    the command must not wait for them to finish."""
    for future in futures:
        future.cancel()
    for chunk, pid in enumerate(pids):
        if pid and not futures[chunk].done():
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass


def _first_error(futures) -> BaseException:
    """The error a chunk raised (BagError, ...), not the cancellations and broken pool that
    ending the others caused."""
    errors = [f.exception() for f in futures if f.done() and not f.cancelled()]
    errors = [e for e in errors if e is not None]
    own = [e for e in errors if not isinstance(e, BrokenProcessPool)]
    return (own or errors)[0]


def register_on_processes(path, params, workers: int, progress=None):
    """Register `path` in `workers` time chunks on as many local processes; the chunks'
    results (chunked.ChunkResult), in chunk order. The plan may have fewer chunks than
    `workers` (chunked.MIN_CHUNK_S)."""
    plan = plan_for(path, params, workers)
    context = _context()
    shared = context.Array("d", len(plan), lock=False)
    pids = context.Array("q", len(plan), lock=False)
    with ProcessPoolExecutor(max_workers=len(plan), mp_context=context,
                             initializer=_init_worker, initargs=(shared, pids)) as pool:
        futures = [pool.submit(_register, os.fspath(path), params, chunk) for chunk in plan]
        pending = set(futures)
        try:
            while pending:
                done, pending = wait(pending, timeout=_PROGRESS_SECONDS,
                                     return_when=FIRST_EXCEPTION)
                if any(f.exception() is not None for f in done):
                    break
                if progress is not None:
                    progress(int(1000 * sum(shared) / len(plan)), 1000)
        except BaseException:  # interrupted
            _stop(futures, pids)
            raise
        if pending:  # a chunk failed: the others' work is lost anyway
            _stop(futures, pids)
            raise _first_error(futures)
        results = [future.result() for future in futures]
    if progress is not None:
        progress(1000, 1000)
    return results


def registered_in_parallel(path, params, workers: int, progress=None):
    """The io.recording.Recording of `path` registered in `workers` chunks on local
    processes (chunked.recording_of)."""
    return recording_of(register_on_processes(path, params, workers, progress))
