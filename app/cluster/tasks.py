"""What every cluster task shares: on the workers, one task at a time, the worker's address,
thread count and cached scenes; on the client, finished futures fetched and their errors raised."""

import os
import threading

from gridrt.errors import GridrtError
from gridrt.threads import max_threads

from .scheduler import _host

# ---------------------------------------------------------------------------------------------
# on the workers
# ---------------------------------------------------------------------------------------------

#: one task at a time per worker process: a chunk and its pipeline, or a configuration, use the
#: worker's threads, and pipelines are not shared between threads
_LOCK = threading.Lock()
#: the worker's scenes (worker_cached), kept for its next tasks; and its pipeline
_SCENES = {}


def worker_address():
    try:
        from distributed import get_worker  # deferred: the optional cluster extra (distributed), on a worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


def worker_threads(threads, per_host):
    """The thread count of a task on this worker: ``threads``, or this machine's cores divided
    among the workers on it (``per_host``: {host: workers}, as the client saw them)."""
    if threads is not None:
        return min(int(threads), max_threads())
    n = max(1, (per_host or {}).get(_host(worker_address()), 1))
    return max(1, min((os.cpu_count() or 1) // n, max_threads()))


def worker_cached(key, make):
    """``make()``, made once per worker process for ``key`` and kept for its next tasks (a
    scene; at most four kept)."""
    value = _SCENES.get(key)
    if value is None:
        if len(_SCENES) >= 4:
            _SCENES.clear()
        value = _SCENES[key] = make()
    return value


# ---------------------------------------------------------------------------------------------
# on the client
# ---------------------------------------------------------------------------------------------

class Stop(Exception):
    """Ctrl-C during a cluster run (raised after the cluster's work is cancelled)."""


def task_error(fut):
    """The exception of a failed future as one to raise on the client: gridrt's own errors as
    they are (the same message as a local run), a worker lost too often as a GridrtError."""
    exc = fut.exception()
    if isinstance(exc, GridrtError):
        return exc
    if type(exc).__name__ == "KilledWorker":
        return GridrtError(f"the workers running {fut.key} died too often; giving up ({exc})")
    return exc


def fetch_done(futs, timeout=0.2):
    """Wait up to ``timeout`` s for one of ``futs`` ({key: future}) to finish; returns {key:
    result} of those finished.  A task that failed, or returned gridrt's own error
    (``{"error": e}``), raises here.  (Cancelled ones were replaced by a resubmission; lost ones
    Dask runs again.)"""
    from distributed import wait  # deferred: the optional cluster extra (distributed), with a cluster

    try:
        wait(list(futs.values()), timeout=timeout, return_when="FIRST_COMPLETED")
    except TimeoutError:
        pass
    out = {}
    for k, f in futs.items():
        if f.status == "error":
            raise task_error(f)
        if f.status == "finished":
            r = f.result()
            if "error" in r:
                raise r["error"]
            out[k] = r
    return out
