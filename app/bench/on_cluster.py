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

from ..cluster import _LOCK, Cluster, CtrlC, Stop, fetch_done, worker_address, worker_cached

_WORKER = {"machine": None}
def _bench_scene(text):
    """The worker's BenchScene of a --scenes entry, loaded once per worker process."""
    from .util import resolve_scene

    return worker_cached(("bench", text), lambda: resolve_scene(text))


def _machine():
    """This worker's machine record (measured once per worker process)."""
    from .util import machine_info

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


def _scene_facts(text):
    from .main import _has_split

    sc = _bench_scene(text)
    return [{"label": sc.label, "has_split": _has_split(sc.scene)}]


def _build_config(text, params, runs, warmup, render):
    from .sweep import _measure

    sc = _bench_scene(text)
    return _measure(sc.label, sc.scene, [params], runs, warmup, os.cpu_count() or 1, render)


def _frame_config(text, variant, settings, runs, warmup, dt):
    from .main import frame_pipeline, frame_row

    sc = _bench_scene(text)
    pipe = frame_pipeline(sc.scene, variant, **settings)
    smp = []
    for i in range(warmup + runs):
        fr = pipe.step(i * dt)
        if i >= warmup:
            smp.append(fr.stats)
    return [frame_row(sc, pipe, variant, smp, settings["strategy"], settings["packet"], settings["packet_precision"],
                      settings["size"], runs)]


@contextlib.contextmanager
def open_cluster(a):
    """The Cluster of the bench's --workers/--scheduler (one task slot per worker), announced,
    with Ctrl-C handled between configurations (:class:`gridrt.app.cluster.CtrlC`): yields (cluster, pressed)."""
    with CtrlC(local=a.workers is not None) as pressed, \
            Cluster(workers=a.workers, scheduler=a.scheduler, listen=a.listen) as cl:
        pressed.listen()
        print(f"gridrt: measuring on {cl.where}; dashboard: {cl.dashboard}", file=sys.stderr, flush=True)
        yield cl, pressed


def worker_cores(cl):
    """The fewest cores of a worker's machine (the default thread counts' ceiling)."""
    from gridrt.threads import max_threads

    cores = cl.client.run(os.cpu_count)
    return max(1, min(min(cores.values() or [1]), max_threads()))


def run_configs(cl, calls, desc, no_progress=False, unit="config", pressed=lambda: False):
    """Each ``(fn, args)`` of ``calls`` as one task; returns (rows in the order of ``calls``,
    {worker: machine record}).  The first error stops the run and is raised; Ctrl-C cancels
    the cluster's work and raises KeyboardInterrupt."""
    from .util import progress

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


def scene_facts(cl, specs, no_progress=False, pressed=lambda: False):
    rows, _ = run_configs(cl, [(_scene_facts, (s,)) for s in specs], "loading scenes", no_progress, unit="scene",
                          pressed=pressed)
    return rows


def build_calls(specs, strategies, kinds, threads, params, runs, warmup, size):
    """The tasks of ``bench build``, in the order a local run lists its rows."""
    return [(_build_config, (s, params.replace(strategy=st, threads=t, grid=k), runs, warmup, size))
            for s in specs for st in strategies for k in kinds for t in threads]


def frame_calls(plan, settings, runs, warmup, dt):
    """The tasks of ``bench frame``: plan = [(scene text, (threads, traversal, split, kind))]."""
    return [(_frame_config, (s, v, settings, runs, warmup, dt)) for s, v in plan]


def _stream(mib, threads, runs):
    from gridrt.grid.traffic import stream_bandwidth

    return [{"stream": stream_bandwidth(mib, threads, runs=runs)}]


def stream_on_worker(cl, mib, threads, runs, no_progress=False, pressed=lambda: False):
    """The STREAM-like bandwidth figures measured on one worker (the traffic model's machine
    figure: a worker's, since workers measured the builds), and that worker's address."""
    rows, _ = run_configs(cl, [(_stream, (mib, threads, runs))], "memory bandwidth", no_progress, unit="measurement",
                          pressed=pressed)
    return rows[0]["stream"], rows[0]["worker"]
