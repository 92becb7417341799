"""``gridrt dump --workers N`` / ``--scheduler ADDRESS``: the frame dump on a Dask cluster
(:mod:`gridrt.app.cluster`); the files are those of a one-process dump, bit for bit, and
``stats.csv`` gains a ``worker`` column."""

import csv
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gridrt.errors import InputError
from gridrt.pipeline import STATS_COLUMNS

from . import cli
from .cluster import Cluster, CtrlC, Stop, default_chunk, run_chunks


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
    skip = {"func", "workers", "scheduler", "listen", "chunk", "no_progress", "out", "command"}
    args = {k: v for k, v in vars(a).items() if k not in skip}
    if os.path.exists(a.scene):
        args["scene"] = os.path.abspath(a.scene)
    return args


def _write_atomic(path, data):
    tmp = path.with_name(f".{path.name}.part")
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def dump_on_cluster(a):
    from .dump import _fmt

    _check(a)
    out = Path(a.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create output folder {out}: {e.strerror}") from None
    t_start = time.perf_counter()
    with CtrlC(local=a.workers is not None) as pressed, \
            Cluster(workers=a.workers, scheduler=a.scheduler, threads=a.threads, listen=a.listen) as cl:
        pressed.listen()
        up_s = time.perf_counter() - t_start
        each = f"{cl.threads} threads each" if cl.threads else "threads: each machine's cores divided among its workers"
        print(f"gridrt: rendering on {cl.where} ({each}; up in {up_s:.1f} s); dashboard: {cl.dashboard}",
              file=sys.stderr, flush=True)
        n_workers = a.workers or max(1, sum(cl.hosts().values()))
        size = a.chunk or default_chunk(a.frames, n_workers)
        rows = []
        bar = tqdm(total=a.frames, desc=f"dump {a.scene}", unit="frame", disable=a.no_progress, file=sys.stderr)
        with open(out / "stats.csv", "w", newline="") as fh:
            state = {"writer": None}

            def write(i, item, worker):
                name = f"frame_{i:05d}"
                _write_atomic(out / f"{name}.png", item["png"])
                if "t" in item:
                    _write_atomic(out / f"{name}_t.npy", item["t"])
                    _write_atomic(out / f"{name}_id.npy", item["id"])
                stats = item["stats"]
                if state["writer"] is None:
                    extra = [k for k in stats if k not in STATS_COLUMNS]
                    state["writer"] = csv.DictWriter(fh, fieldnames=list(STATS_COLUMNS) + extra + ["worker"],
                                                     extrasaction="ignore")
                    state["writer"].writeheader()
                state["writer"].writerow({**{k: _fmt(v) for k, v in stats.items()}, "worker": worker})
                fh.flush()
                rows.append(stats)
                bar.update(1)
                bar.set_postfix(build=f"{stats['build_ms']:.1f}ms", render=f"{stats['render_ms']:.1f}ms")

            try:
                threads = run_chunks(cl, _worker_args(a), a.frames, size, write, pressed)
            except Stop as s:
                bar.close()
                print(f"gridrt: interrupted: {s.args[0]} of {a.frames} frames written to {out}/ (each whole, "
                      "with its stats row); the cluster is stopped", file=sys.stderr, flush=True)
                raise KeyboardInterrupt from None
            finally:
                bar.close()
    wall = time.perf_counter() - t_start
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    print(
        f"wrote {a.frames} frames to {out}/ ({rows[0]['triangles']} triangles, {rows[0]['width']}x{rows[0]['height']}, "
        f"{rows[0]['strategy']}, {rows[0]['grid']} grid) on {cl.where} in chunks of {size}, "
        f"{'/'.join(map(str, sorted(threads)))} threads per worker: {a.frames / wall:.2f} frames/s in {wall:.1f} s "
        f"(cluster start {up_s:.1f} s); median build {med('build_ms'):.2f} ms, render {med('render_ms'):.2f} ms, "
        f"frame {med('frame_ms'):.2f} ms"
    )
    return 0
