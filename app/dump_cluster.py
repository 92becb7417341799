"""``gridrt dump --workers N`` / ``--scheduler ADDRESS``: the frame dump on a Dask cluster
(:mod:`gridrt.app.cluster`); the files are those of a one-process dump, bit for bit, and
``stats.csv`` gains a ``worker`` column."""

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gridrt.errors import GridrtError, InputError

from . import cli
from .cluster import Cluster, CtrlC, Stop, default_chunk, run_chunks
from .frame_out import FrameWriteError, FrameWriter, StopSignals, run_settings


def _check(a):
    """Everything the client can check without loading the scene (the workers load it; --frames,
    --t0 and --dt are checked by the dump already)."""
    if a.chunk is not None and a.chunk < 1:
        raise InputError(f"--chunk must be at least 1, got {a.chunk}")
    cli.camera_from_args(a)
    cli.grid_params(a)
    cli.render_params(a)
    cli.scene_spec(a)


def _worker_args(a):
    """The options a worker needs to build the dump's pipeline (a plain dict): a scene file
    given by a path that exists here is made absolute (a local cluster's workers, or workers that
    see the same folders, find it from any working directory)."""
    skip = {"func", "workers", "scheduler", "listen", "chunk", "no_progress", "out", "command", "overwrite", "resume"}
    args = {k: v for k, v in vars(a).items() if k not in skip}
    if os.path.exists(a.scene):
        args["scene"] = os.path.abspath(a.scene)
    return args


def dump_on_cluster(a):
    from .dump import nothing_to_do, replace_mode, resumed

    _check(a)
    out = Path(a.out)
    writer = FrameWriter(out, run_settings(a), a.frames, mode=replace_mode(a))
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
                    threads = run_chunks(cl, _worker_args(a), a.frames, size, write, lambda: pressed() or term(),
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
