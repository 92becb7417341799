"""BENCHMARKS.md section 13, "Incoherent rays interleaved": batch casts of random rays with their
single rays traced one at a time against the same casts with them traced interleaved
(gridrt.trace.stream), taken in turns in one process.

    .venv/bin/python scripts/interleaved_rays.py

makes the table (512x512 rays, medians of 7 turns after one untimed turn each); ``--size 32 --runs 1
--scenes icosphere:1280`` is a quick check.  Each scene's ``bench peers`` random rays (from inside
its bounds, gridrt.app.bench.peers) go through ``gridrt.trace.batch.cast_grouped`` (nearest hit,
watertight, the default MAX_CELLS) over a uniform grid (``GridParams()``) at t = 0, with
``batch.streams`` answering False, then True, in turns, whatever the mesh's size; pass 1 finds no
packet among such rays and pass 2 traces them singly, so the two differ only in how those are
traced.  Mrays/s are medians; the ratio is interleaved time over one-at-a-time time; "same" says
whether every ray's triangle, t, u and v agree bit for bit.
"""

import argparse
import time

import numba
import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.output import md_table
from gridrt.app.bench.peers import peer_rays
from gridrt.app.bench.scenes import resolve_scene
from gridrt.config import GridParams
from gridrt.grid.build import GridBuilder
from gridrt.trace import batch
from gridrt.trace.grids import grid_arrays
from tables import add_out_option, items, keep_output, print_settings, scene_label

#: the table's scenes (section 13's single-ray scenes and the marbles)
SCENES = "icosphere:20480:twist,lucy:twist,icosphere:327680:twist,marbles:640000,icosphere:1310720:twist"
SIZE, RUNS, THREADS = 512, 7, "1,2"
HEADER = ["scene, rays", "threads", "one at a time Mrays/s", "interleaved Mrays/s", "time ratio", "same"]


def measure(g, o, d, threads, runs):
    """(Mrays/s one at a time, Mrays/s interleaved, the same hits) of cast_grouped on threads
    threads, the two ways in turns (one untimed turn, then runs timed ones, medians)."""
    n = len(o)
    outs = {way: (np.empty(n), np.empty(n, np.int32), np.empty(n), np.empty(n)) for way in (False, True)}
    times = {False: [], True: []}
    real = batch.streams
    numba.set_num_threads(threads)
    try:
        for turn in range(runs + 1):
            for way in (False, True):
                batch.streams = lambda g, way=way: way
                t0 = time.perf_counter()
                batch.cast_grouped(g, o, d, 0.0, np.inf, True, False, outs[way])
                if turn:
                    times[way].append(time.perf_counter() - t0)
    finally:
        batch.streams = real
    same = all(np.array_equal(a, b) for a, b in zip(outs[False], outs[True]))
    return n / np.median(times[False]) / 1e6, n / np.median(times[True]) / 1e6, same


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", default=SCENES, help="comma-separated bench scene specs (default: the table's)")
    p.add_argument("--size", type=int, default=SIZE, help=f"size x size rays (default {SIZE}, the table's)")
    p.add_argument("--runs", type=int, default=RUNS, help=f"timed turns, medians kept (default {RUNS}, the table's)")
    p.add_argument("--threads", default=THREADS, help=f"thread counts (default {THREADS}, the table's)")
    add_out_option(p)
    a = p.parse_args(argv)
    keep_output(a.out)
    print_settings(p, a)
    print()
    rows = []
    for text in items(a.scenes):
        sc = resolve_scene(text)
        _origin, _cam, _o32, _d32, o, d = peer_rays(sc, a.size, "random")
        tris = np.ascontiguousarray(sc.scene.triangles_at(0.0, origin=_origin), np.float32)
        g = grid_arrays(GridBuilder(GridParams()).build(tris), tris)
        for threads in [int(x) for x in items(a.threads)]:
            one, inter, same = measure(g, o, d, threads, a.runs)
            rows.append([f"{scene_label(sc.label, len(tris))}, random", str(threads), f"{one:.2f}", f"{inter:.2f}",
                         f"{one / inter:.2f}", "yes" if same else "no"])
            print(" | ".join(rows[-1]), flush=True)
    print()
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
