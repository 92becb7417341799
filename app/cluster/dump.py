"""``gridrt dump --workers N`` / ``--scheduler ADDRESS``: the frame dump on a Dask cluster
(:mod:`gridrt.app.cluster`); the files are those of a one-process dump, bit for bit, and
``stats.csv`` gains a ``worker`` column."""

import os
import signal
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gridrt.errors import GridrtError, InputError
from gridrt.frame import FrameSpec
from gridrt.pipeline import FramePipeline

from ..frame_out import (
    FrameWriteError, FrameWriter, StopSignals, encode_frame, nothing_to_do, replace_mode, resumed, run_settings,
    run_spec,
)
from .scheduler import Cluster, CtrlC
from .tasks import _LOCK, Stop, fetch_done, worker_address, worker_cached, worker_threads

#: the worker's pipeline of the last spec it rendered, kept for its next chunks
_PIPE = {}


def render_chunk(wire, save_buffers, start, stop, origin, per_host=None):
    """Frames ``start`` .. ``stop``-1 of the dump of the FrameSpec ``wire`` (:meth:`FrameSpec.to_wire`,
    read back and checked here by :meth:`FrameSpec.from_wire`) with its ``.npy`` buffers when
    ``save_buffers``, as its one-process run would render them; ``origin``: where the pipeline stood after frame
    ``start``-1 (None: where the first frame left it).  Returns a dict: ``origin_in`` (the
    origin the chunk started from; None for frame 0), ``origins`` (after each frame), ``worker``,
    ``threads``, ``warnings`` ((category, message) pairs) and ``frames``: per frame its PNG
    bytes, ``.npy`` bytes of the buffers when asked, its stats row and origin
    (:func:`gridrt.app.frame_out.encode_frame`)."""
    with _LOCK:
        try:
            with warnings.catch_warnings(record=True) as caught:  # (warned again on the client, once)
                warnings.simplefilter("always")
                r = _render_chunk(FrameSpec.from_wire(wire), bool(save_buffers), start, stop, origin, per_host)
            r["warnings"] = list(dict.fromkeys((w.category, str(w.message)) for w in caught))
            return r
        except GridrtError as e:  # the run's own error (a scene that does not load...): a result, not a failure
            return {"error": e}


def _render_chunk(spec, save_buffers, start, stop, origin, per_host):
    threads = worker_threads(spec.grid.threads, per_host)
    spec = spec.replace(grid=spec.grid.replace(threads=threads), render=spec.render.replace(threads=threads))
    pipe = _PIPE.get(spec)
    if pipe is None:
        _PIPE.clear()
        pipe = _PIPE[spec] = FramePipeline.from_spec(spec, scene=worker_cached(spec.scene, spec.scene.make))
    pipe.resume(start, spec.view.t0, origin)
    origin_in = None if start == 0 else pipe.origin.copy()
    frames, origins = [], []
    for i in range(start, stop):
        fr = pipe.step(spec.view.time(i))
        frames.append(encode_frame(fr, save_buffers))  # (the files of a one-process dump, by construction)
        origins.append(pipe.origin.copy())
    return {"start": start, "stop": stop, "origin_in": origin_in, "origins": origins,
            "worker": worker_address(), "threads": threads, "frames": frames}


def chunks(n, size, begin=0):
    """[(start, stop)] cutting frames ``begin`` .. n-1 into chunks of ``size`` consecutive frames."""
    return [(s, min(s + size, n)) for s in range(begin, n, size)]


def default_chunk(frames, workers):
    """Frames per chunk: about four chunks per worker (so a worker lost or slow costs little),
    at most 16 frames (a chunk's images travel in one message), at least 1."""
    return max(1, min(16, -(-frames // (4 * max(1, workers)))))


def run_chunks(cl, spec, save_buffers, frames, size, write, pressed=lambda: False, begin=0, origin=None):
    """Render ``frames`` frames of the FrameSpec ``spec`` (shipped as :meth:`FrameSpec.to_wire`; with
    its ``.npy`` buffers when ``save_buffers``) on the Cluster ``cl`` in chunks of
    ``size`` and hand each frame, in order, to ``write(i, item, worker)`` (exactly once each).
    ``begin``: the first frame to render (a resumed dump), ``origin``: where the pipeline stood
    after the frame before it.
    Ctrl-C (``pressed()``: a :class:`CtrlC`) stops the run between frames: raises
    :class:`Stop` with the frames written.
    Returns the workers' thread counts seen."""
    client = cl.client
    per_host = cl.hosts()
    parts = chunks(frames, size, begin)
    futs, sent = {}, {}
    wire = spec.to_wire()

    def submit(c, origin):
        if c in futs:
            futs[c].cancel()
        s, e = parts[c]
        sent[c] = origin
        futs[c] = client.submit(render_chunk, wire, save_buffers, s, e, origin, per_host, pure=False,
                                key=f"gridrt-frames-{s:05d}-{e - 1:05d}-{os.urandom(4).hex()}")

    for c in range(len(parts)):
        submit(c, origin)
    results, threads, warned = {}, set(), set()
    ahead = 2 * max(1, sum(per_host.values())) + 2
    nxt, last = 0, origin  # next chunk to write; the origin the last chunk written ended with
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
                if last is not None and not np.array_equal(r["origin_in"], last):
                    del results[nxt]  # started from a stale frame of reference: again, from the right one
                    submit(nxt, last)
                    break
                first = r["origins"][0] if r["origin_in"] is None else r["origin_in"]
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


def dump_on_cluster(a, spec):
    """The dump of ``spec`` (FrameSpec, checked on the client: the workers load the scene) with
    the options ``a`` (frames, output, cluster) on a Dask cluster."""
    if a.chunk is not None and a.chunk < 1:
        raise InputError(f"--chunk must be at least 1, got {a.chunk}")
    out = Path(a.out)
    writer = FrameWriter(out, spec, run_settings(a), a.frames, mode=replace_mode(a))
    rows = []
    error = signum = None
    t_start = time.perf_counter()
    # SIGTERM stops the run between frames, as Ctrl-C does (CtrlC)
    with StopSignals(signals=(signal.SIGTERM,), defer=True) as term:
        try:
            start = writer.check()
            if start >= a.frames:
                return nothing_to_do(writer, start)
            with CtrlC(local=a.workers is not None) as pressed, \
                    Cluster(workers=a.workers, scheduler=a.scheduler, threads=a.threads, listen=a.listen) as cl:
                pressed.listen()
                up_s = time.perf_counter() - t_start
                each = (f"{cl.threads} threads each" if cl.threads
                        else "threads: each machine's cores divided among its workers")
                print(f"gridrt: rendering on {cl.where} ({each}; up in {up_s:.1f} s); dashboard: {cl.dashboard}",
                      file=sys.stderr, flush=True)
                n_workers = a.workers or max(1, sum(cl.hosts().values()))
                size = a.chunk or default_chunk(a.frames - start, n_workers)
                writer.begin()
                bar = tqdm(total=a.frames, initial=start, desc=f"dump {a.scene}", unit="frame",
                           disable=a.no_progress, file=sys.stderr)

                def write(i, item, worker):
                    writer.write(i, item, {"worker": worker})
                    stats = item["stats"]
                    rows.append(stats)
                    bar.update(1)
                    bar.set_postfix(build=f"{stats['build_ms']:.1f}ms", render=f"{stats['render_ms']:.1f}ms")

                try:
                    threads = run_chunks(cl, run_spec(spec), a.save_buffers, a.frames, size, write,
                                         lambda: pressed() or term(),
                                         begin=start, origin=writer.origin)
                except Stop:
                    signum = signal.SIGINT if pressed() else signal.SIGTERM
                finally:
                    bar.close()
        except GridrtError as e:
            if not isinstance(e, FrameWriteError) and (not writer.begun or writer.done == 0):
                raise  # (no frame to speak of: the error as a one-process run gives it)
            error = e
        except KeyboardInterrupt:  # Ctrl-C before the cluster started
            signum = signal.SIGINT
        finally:
            writer.close()
    if error is not None or signum is not None:  # (the cluster is stopped)
        return writer.stopped(error=error, signum=signum)
    wall = time.perf_counter() - t_start
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    print(
        f"wrote {len(rows)} frames to {out}/{resumed(start, a.frames)} ({rows[0]['triangles']} triangles, "
        f"{rows[0]['width']}x{rows[0]['height']}, {rows[0]['strategy']}, {rows[0]['grid']} grid) on {cl.where} in "
        f"chunks of {size}, {'/'.join(map(str, sorted(threads)))} threads per worker: {len(rows) / wall:.2f} frames/s "
        f"in {wall:.1f} s (cluster start {up_s:.1f} s); median build {med('build_ms'):.2f} ms, render "
        f"{med('render_ms'):.2f} ms, frame {med('frame_ms'):.2f} ms"
    )
    return 0
