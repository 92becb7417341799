"""Frames and benchmark configurations on a Dask cluster (``--workers N``, ``--scheduler ADDRESS``).

Frames are independent, so a sequence spreads over processes and machines perfectly; the cluster
is Dask's ``distributed`` scheduler (an optional extra: ``pip install 'gridrt[cluster]'``): a local
cluster of worker processes started here (``--workers N``), or an existing one (``dask scheduler``
and ``dask worker`` processes anywhere, ``--scheduler tcp://HOST:PORT``).  Without either flag
nothing here is imported.

A dump is cut into chunks of consecutive frames.  Each worker process loads the scene once and
keeps it, with its pipeline (kernels warmed, grids and buffers allocated), for its next chunks;
it renders a chunk, encodes the PNGs (and the ``.npy`` buffers) and sends the bytes back.  The
client writes every file itself: the workers need no folder in common with it (a cluster of
machines seldom has one), the output folder is written by one process only, and a frame is
written only once, whatever the retries.  The files are written in frame order, each PNG and
buffer whole (written under a temporary name, then renamed), and then its row of ``stats.csv``.

A pipeline carries state from frame to frame: the frame of reference the scene is gridded in
(chosen at the first frame, moved when the scene drifts far), the camera that frames the scene at
the first frame, and a static scene's grid.  A worker that starts a chunk in the middle takes that
state with :meth:`gridrt.pipeline.FramePipeline.resume`: the first frame's camera and origin (it
places the first frame itself, without rendering it), and the origin the previous chunk ended
with when the client knows it.  A chunk whose start differs from where its predecessor ended (the
scene moved its frame in between: rare) is rendered again from there; so the output is that of a
one-process dump, bit for bit.

Faults: a worker that dies loses its chunks to Dask, which runs them again on the other workers
(chunks are pure: same input, same bytes).  A task's error (a scene that does not load, say) is
raised once, on the client, and stops the run.
"""

import io
import os
import threading
import warnings

import numpy as np

from gridrt.errors import GridrtError, InputError

def install_hint():
    """How to get the cluster extra, with the pip of the running interpreter."""
    from gridrt.commands import pip_command

    pip = pip_command()
    return (f"{pip} install 'gridrt[cluster]' (in a checkout: {pip} install -e '.[cluster]'; or {pip} install "
            "distributed bokeh)")

#: seconds to wait for a --scheduler to answer
CONNECT_TIMEOUT = 5


def add_cluster_args(p, what="frames"):
    g = p.add_argument_group("cluster (Dask; needs the extra: pip install 'gridrt[cluster]')")
    g.add_argument("--workers", type=int, default=None,
                   help=f"spread the {what} over a local Dask cluster of this many worker processes, each with "
                        "--threads threads (default: the cores divided among the workers)")
    g.add_argument("--scheduler", default=None,
                   help=f"spread the {what} over an existing Dask cluster: its scheduler's address, e.g. "
                        "tcp://10.0.0.5:8786 (start one with `dask scheduler` and `dask worker ADDRESS --nthreads 1`; "
                        "each worker uses --threads threads, default: its machine's cores divided among the "
                        "workers on it)")
    return g


def wants_cluster(a):
    """True when the parsed arguments ask for a cluster (validated)."""
    workers, scheduler = getattr(a, "workers", None), getattr(a, "scheduler", None)
    if workers is not None and scheduler is not None:
        raise InputError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if scheduler is not None and not str(scheduler).strip():
        raise InputError("--scheduler needs an address, e.g. tcp://127.0.0.1:8786")
    return workers is not None or scheduler is not None


def import_distributed():
    """The ``distributed`` module, or an InputError saying how to install it."""
    try:
        import distributed
    except ImportError as e:
        raise InputError(f"--workers and --scheduler need Dask's distributed scheduler, which is not installed "
                         f"({e}); install the cluster extra: {install_hint()}") from None
    return distributed


class Cluster:
    """A Dask client on a local cluster of ``workers`` processes (started here, stopped on
    :meth:`close`) or on the scheduler at ``scheduler``.  ``threads``: threads per worker (None:
    a local cluster's cores divided among its workers; an existing cluster's workers divide their
    own machine's cores among the workers on it)."""

    def __init__(self, workers=None, scheduler=None, threads=None):
        dist = import_distributed()
        import logging

        self.threads = threads
        self.cluster = None
        self.client = None
        if workers is not None:
            cores = os.cpu_count() or 1
            if threads is None:
                self.threads = max(1, cores // workers)
            if workers * self.threads > cores:
                warnings.warn(f"{workers} workers x {self.threads} threads = {workers * self.threads} threads on "
                              f"{cores} cores: they compete for them (--threads sets the threads per worker)",
                              stacklevel=2)
            # one task at a time per worker (a chunk or a configuration uses its own threads);
            # logs above errors only: a worker killed on purpose is not news
            self.cluster = dist.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                             silence_logs=logging.ERROR, dashboard_address=":8787")
            try:
                self.client = dist.Client(self.cluster)
                from .cluster_plugin import IgnoreSigint

                self.client.register_plugin(IgnoreSigint())  # (a worker restarted later ignores Ctrl-C too)
            except BaseException:
                self.cluster.close()
                raise
            self.where = f"a local cluster of {workers} worker processes"
        else:
            address = str(scheduler).strip()
            if "://" not in address:
                address = "tcp://" + address
            try:
                self.client = dist.Client(address, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, ValueError) as e:
                raise InputError(f"cannot reach the Dask scheduler at {address} within {CONNECT_TIMEOUT} s "
                                 f"({' '.join(str(e).split()) or type(e).__name__}); is `dask scheduler` running "
                                 "there, and is the port open?") from None
            info = self.client.scheduler_info()
            n = len(info.get("workers", {}))
            self.where = f"the Dask cluster at {address} ({n} workers)"
        self.dashboard = self.client.dashboard_link

    def hosts(self):
        """{host: workers on it} of the workers connected now."""
        out = {}
        for addr in self.client.scheduler_info().get("workers", {}):
            h = _host(addr)
            out[h] = out.get(h, 0) + 1
        return out

    def close(self):
        try:
            if self.client is not None:
                self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class CtrlC:
    """Ctrl-C during a cluster run, as a context manager around the cluster: while a ``local``
    cluster starts (a second or two) SIGINT is ignored (its worker processes share the terminal's
    process group, so Ctrl-C reaches them too; they inherit "ignore" and leave it to the client,
    which stops them); after :meth:`listen` (at once for an existing cluster) it raises a flag, which the client's loop checks between
    frames (``ctrl_c()`` is true once pressed: the loop stops with every frame written whole).
    The handler in place before is restored on exit.  Outside the main thread it does nothing."""

    def __init__(self, local=True):
        self.flag = threading.Event()
        self.old = None
        self.local = local

    def __enter__(self):
        import signal

        if threading.current_thread() is threading.main_thread():
            self.old = signal.signal(signal.SIGINT, signal.SIG_IGN)
            if not self.local:  # no worker processes start here: heard at once, acted on once connected
                self.listen()
        return self

    def listen(self):
        import signal

        if self.old is not None:
            signal.signal(signal.SIGINT, lambda *_: self.flag.set())

    def __call__(self):
        return self.flag.is_set()

    def __exit__(self, *exc):
        import signal

        if self.old is not None:
            signal.signal(signal.SIGINT, self.old)


def _host(address):
    """The host part of a Dask address (``tcp://10.0.0.5:40123`` -> ``10.0.0.5``)."""
    s = str(address).split("://", 1)[-1]
    return s.rsplit(":", 1)[0] if ":" in s else s


# ---------------------------------------------------------------------------------------------
# on the workers
# ---------------------------------------------------------------------------------------------

#: one task at a time per worker process: a chunk and its pipeline, or a configuration, use the
#: worker's threads, and pipelines are not shared between threads
_LOCK = threading.Lock()
#: the worker's scenes (worker_cached), kept for its next tasks; and its pipeline
_SCENES = {}
_PIPE = {}


def worker_address():
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


def worker_threads(threads, per_host):
    """The thread count of a task on this worker: ``threads``, or this machine's cores divided
    among the workers on it (``per_host``: {host: workers}, as the client saw them)."""
    from gridrt.threads import max_threads

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


def render_chunk(args, start, stop, origin, per_host=None):
    """Frames ``start`` .. ``stop``-1 of the dump ``args`` (the dump's parsed options, a dict),
    as its one-process run would render them; ``origin``: where the pipeline stood after frame
    ``start``-1 (None: where the first frame left it).  Returns a dict: ``origin_in`` (the
    origin the chunk started from; None for frame 0), ``origins`` (after each frame), ``worker``,
    ``threads``, ``warnings`` ((category, message) pairs) and ``frames``: per frame its PNG
    bytes, ``.npy`` bytes of the buffers when asked, and its stats row."""
    import argparse

    with _LOCK:
        try:
            with warnings.catch_warnings(record=True) as caught:  # (warned again on the client, once)
                warnings.simplefilter("always")
                r = _render_chunk(argparse.Namespace(**args), start, stop, origin, per_host)
            r["warnings"] = list(dict.fromkeys((w.category, str(w.message)) for w in caught))
            return r
        except GridrtError as e:  # the run's own error (a scene that does not load...): a result, not a failure
            return {"error": e}


def _render_chunk(a, start, stop, origin, per_host):
    from PIL import Image

    from . import cli

    a.threads = worker_threads(a.threads, per_host)
    key = repr(sorted(vars(a).items()))
    pipe = _PIPE.get(key)
    if pipe is None:
        _PIPE.clear()
        pipe = _PIPE[key] = cli.pipeline_from_args(a, scene=worker_cached(cli.scene_spec(a), cli.scene_spec(a).make))
    pipe.resume(start, a.t0, origin)
    origin_in = None if start == 0 else pipe.origin.copy()
    frames, origins = [], []
    for i in range(start, stop):
        fr = pipe.step(a.t0 + i * a.dt)
        buf = io.BytesIO()
        Image.fromarray(fr.image[:, :, :3]).save(buf, format="PNG")
        item = {"png": buf.getvalue(), "stats": dict(fr.stats)}
        if a.save_buffers:
            item["t"], item["id"] = _npy(fr.t), _npy(fr.tri)
        frames.append(item)
        origins.append(pipe.origin.copy())
    return {"start": start, "stop": stop, "origin_in": origin_in, "origins": origins,
            "worker": worker_address(), "threads": a.threads, "frames": frames}


def _npy(arr):
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()




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
    from distributed import wait

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


def chunks(n, size):
    """[(start, stop)] cutting frames 0 .. n-1 into chunks of ``size`` consecutive frames."""
    return [(s, min(s + size, n)) for s in range(0, n, size)]


def default_chunk(frames, workers):
    """Frames per chunk: about four chunks per worker (so a worker lost or slow costs little),
    at most 16 frames (a chunk's images travel in one message), at least 1."""
    return max(1, min(16, -(-frames // (4 * max(1, workers)))))


def run_chunks(cl, args, frames, size, write, pressed=lambda: False):
    """Render ``frames`` frames of the dump ``args`` (dict) on the Cluster ``cl`` in chunks of
    ``size`` and hand each frame, in order, to ``write(i, item, worker)`` (exactly once each).
    Ctrl-C (``pressed()``: a :class:`CtrlC`) stops the run between frames: raises
    :class:`Stop` with the frames written.
    Returns the workers' thread counts seen."""
    client = cl.client
    per_host = cl.hosts()
    parts = chunks(frames, size)
    futs, sent = {}, {}

    def submit(c, origin):
        if c in futs:
            futs[c].cancel()
        s, e = parts[c]
        sent[c] = origin
        futs[c] = client.submit(render_chunk, args, s, e, origin, per_host, pure=False,
                                key=f"gridrt-frames-{s:05d}-{e - 1:05d}-{os.urandom(4).hex()}")

    for c in range(len(parts)):
        submit(c, None)
    results, threads, warned = {}, set(), set()
    ahead = 2 * max(1, sum(per_host.values())) + 2
    nxt, last = 0, None  # next chunk to write; the origin the last chunk written ended with
    written = 0
    try:
        while nxt < len(parts):
            if pressed():
                raise Stop(written)
            # results are fetched up to ``ahead`` chunks past the next to write; later ones wait on
            # their workers (the client holds a few chunks, not the sequence, when it falls behind)
            window = {c: f for c, f in futs.items() if nxt <= c < nxt + ahead and c not in results}
            for c, r in fetch_done(window).items():
                results[c] = r
                for category, message in r["warnings"]:
                    if (category, message) not in warned:  # once, as a one-process dump warns
                        warned.add((category, message))
                        warnings.warn(message, category, stacklevel=2)
            while nxt in results and not pressed():
                r = results[nxt]
                if nxt > 0 and not np.array_equal(r["origin_in"], last):
                    del results[nxt]  # started from a stale frame of reference: again, from the right one
                    submit(nxt, last)
                    break
                first = r["origins"][0] if nxt == 0 else r["origin_in"]
                for k, item in enumerate(r["frames"]):
                    if pressed():
                        raise Stop(written)
                    write(r["start"] + k, item, r["worker"])
                    written += 1
                threads.add(r["threads"])
                last = r["origins"][-1]
                if not np.array_equal(last, first):
                    # the scene moved its frame in this chunk: the later chunks start from here
                    for d in range(nxt + 1, len(parts)):
                        if d not in results or not np.array_equal(results[d]["origin_in"], last):
                            results.pop(d, None)
                            if sent.get(d) is None or not np.array_equal(sent[d], last):
                                submit(d, last)
                del results[nxt]
                futs.pop(nxt).release()
                nxt += 1
        if pressed():
            raise Stop(written)
    finally:
        for f in futs.values():
            f.cancel()
    return threads
