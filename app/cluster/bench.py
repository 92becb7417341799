"""``gridrt bench build`` and ``bench frame`` with ``--workers N`` / ``--scheduler ADDRESS``: the
configurations spread over a Dask cluster (:mod:`gridrt.app.cluster`), one configuration per
worker at a time.  Each configuration is measured whole inside one worker (its warm-up and timed
runs, the medians), exactly as a local run measures it, so its timings mean what they mean
locally; every row names the worker that ran it and carries its machine record (CPU, cores, the
1-minute load when the configuration started), and ``machine.json`` holds every worker's full
record under ``workers``.

Workers that share a machine share its cores: a configuration of T threads on a worker whose
neighbours are busy competes with them.  For scaling figures comparable with a local run give
each worker a machine of its own (or run one worker per machine).
"""

import contextlib
import os
import sys

from gridrt.errors import GridrtError
from gridrt.grid.traffic import stream_bandwidth
from gridrt.threads import max_threads

from ..bench.machine import machine_info
from ..bench.output import progress
from ..bench.scenes import resolve_scene
from .scheduler import Cluster, CtrlC
from .tasks import _LOCK, Stop, fetch_done, worker_address, worker_cached

_WORKER = {"machine": None}
def _bench_scene(text):
    """The worker's BenchScene of a --scenes entry, loaded once per worker process."""
    return worker_cached(("bench", text), lambda: resolve_scene(text))


def _machine():
    """This worker's machine record (measured once per worker process)."""
    if _WORKER["machine"] is None:
        info = machine_info([])
        info.pop("threads_used", None)
        info.pop("command", None)
        info["worker"] = worker_address()
        _WORKER["machine"] = info
    return _WORKER["machine"]


def _run(fn, *args):
    """``fn(*args)`` on this worker, one at a time per worker process; returns {"rows", "machine"}
    with the worker columns on every row, or {"error"} for gridrt's own errors."""
    with _LOCK:
        try:
            machine = _machine()
            try:
                load = round(os.getloadavg()[0], 2)
            except OSError:
                load = float("nan")
            rows = fn(*args)
        except GridrtError as e:
            return {"error": e}
        for r in rows:
            r.update(worker=machine["worker"], worker_cpu=machine["cpu"], worker_cores=machine["cores"],
                     worker_load_start=load)
        return {"rows": rows, "machine": machine}


@contextlib.contextmanager
def open_cluster(a):
    """The Cluster of the bench's --workers/--scheduler (one task slot per worker), announced,
    with Ctrl-C handled between configurations (:class:`gridrt.app.cluster.scheduler.CtrlC`): yields (cluster, pressed)."""
    with CtrlC(local=a.workers is not None) as pressed, \
            Cluster(workers=a.workers, scheduler=a.scheduler, listen=a.listen) as cl:
        pressed.listen()
        print(f"gridrt: measuring on {cl.where}; dashboard: {cl.dashboard}", file=sys.stderr, flush=True)
        yield cl, pressed


def worker_cores(cl):
    """The fewest cores of a worker's machine (the default thread counts' ceiling)."""
    cores = cl.client.run(os.cpu_count)
    return max(1, min(min(cores.values() or [1]), max_threads()))


def run_configs(cl, calls, desc, no_progress=False, unit="config", pressed=lambda: False):
    """Each ``(fn, args)`` of ``calls`` as one task; returns (rows in the order of ``calls``,
    {worker: machine record}).  The first error stops the run and is raised; Ctrl-C cancels
    the cluster's work and raises KeyboardInterrupt."""
    client = cl.client
    futs = [client.submit(_run, fn, *args, pure=False) for fn, args in calls]
    results = [None] * len(futs)
    bar = progress(len(futs), desc, no_progress)
    try:
        while any(r is None for r in results):
            if pressed():
                raise Stop(sum(r is not None for r in results))
            for i, r in fetch_done({i: f for i, (f, r) in enumerate(zip(futs, results)) if r is None}).items():
                results[i] = r
                bar.update(1)
    except Stop as s:
        bar.close()
        print(f"gridrt: interrupted after {s.args[0]} of {len(futs)} {unit}s; the cluster's work is cancelled",
              file=sys.stderr, flush=True)
        raise KeyboardInterrupt from None
    finally:
        bar.close()
        for f in futs:
            f.cancel()
    rows, machines = [], {}
    for r in results:
        rows += r["rows"]
        machines[r["machine"]["worker"]] = r["machine"]
    return rows, machines


def _stream(mib, threads, runs):
    return [{"stream": stream_bandwidth(mib, threads, runs=runs)}]


def stream_on_worker(cl, mib, threads, runs, no_progress=False, pressed=lambda: False):
    """The STREAM-like bandwidth figures measured on one worker (the traffic model's machine
    figure: a worker's, since workers measured the builds), and that worker's address."""
    rows, _ = run_configs(cl, [(_stream, (mib, threads, runs))], "memory bandwidth", no_progress, unit="measurement",
                          pressed=pressed)
    return rows[0]["stream"], rows[0]["worker"]
