"""BENCHMARKS.md section 13, "The single-ray DDA": ``trace_ray`` in a loop over the ``bench peers``
rays of each scene and view, one thread, ns a ray (the best of the timed runs after an untimed
compiling run) with the cells visited, triangle tests and hit fraction a ray.

    .venv/bin/python scripts/single_ray_dda.py

makes the table (512x512 rays, the best of 5); ``--size 16 --runs 1`` is a quick check.  Each ray
goes through :func:`gridrt.trace.traverse.trace_ray` (nearest hit, watertight test, t in (0, inf))
on a uniform grid (``GridParams()``) over the scene at t = 0, the frame the rays are made in; the
rays are those of ``bench peers`` (:mod:`gridrt.app.bench.peers`): the scene's camera ("frame"),
that camera moved in until the scene fills the view ("fill"), or random rays in the scene's
bounds ("random").
"""

import argparse

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.output import md_table
from gridrt.app.bench.peers import peer_rays
from gridrt.app.bench.scenes import resolve_scene
from gridrt.app.bench.stats import timings
from gridrt.config import GridParams
from gridrt.grid.build import GridBuilder
from gridrt.trace.grids import grid_arrays
from gridrt.trace.traverse import SCRATCH, trace_ray
from numba import njit

from tables import add_out_option, add_ray_options, items, keep_output, print_settings, scene_label

#: the table's scenes and ray sets (section 13: the ``bench peers`` scenes and views)
SCENES = "cesium,icosphere:20480:twist,lucy:twist,icosphere:1310720:twist"
VIEWS = "random,fill,frame"
SIZE, RUNS = 512, 5
#: what the script does not let an option change
FIXED = ("a uniform grid, GridParams(), over the scene at t = 0; "
         "trace_ray in a loop on one thread; the best of the timed runs after one untimed run")
HEADER = ["scene, rays", "cells, tests a ray", "ns a ray"]


@njit(cache=True)
def trace_all(g, o, d, mailbox, tri, cells, tests):
    """Each ray i of (origins o, directions d) through trace_ray; its triangle, cells visited and
    triangle tests into tri[i], cells[i], tests[i]."""
    for i in range(o.shape[0]):
        f, t, u, v, nc, nt = trace_ray(g, (o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]), 0.0, np.inf,
                                       True, False, mailbox)
        tri[i] = f
        cells[i] = nc
        tests[i] = nt


def measure(sc, g, view, size, runs):
    """(label, cells a ray, tests a ray, best ns a ray) of the BenchScene sc, its GridArrays g at
    t = 0 and one view."""
    _origin, _cam, _o32, _d32, o, d = peer_rays(sc, size, view)
    n = len(o)
    mailbox = np.empty(SCRATCH, np.int32)
    tri, cells, tests = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    # one untimed call first (it compiles trace_all), then the best of the timed ones
    _median, best_ms, _worst = timings(lambda: trace_all(g, o, d, mailbox, tri, cells, tests), runs)
    label = f"{scene_label(sc.label, len(g.tris))}, {view} (hit {(tri >= 0).mean():.2f})"
    return label, cells.mean(), tests.mean(), best_ms * 1e6 / n


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_ray_options(p, SCENES, VIEWS, SIZE, RUNS, "ray sets", "timed runs")
    add_out_option(p)
    a = p.parse_args(argv)
    keep_output(a.out)
    scenes, views = items(a.scenes), items(a.views)
    print_settings(p, a)
    print(f"fixed: {FIXED}")
    print()
    rows = []
    for text in scenes:
        sc = resolve_scene(text)
        tris = np.ascontiguousarray(sc.scene.triangles_at(0.0, origin=sc.scene.frame_origin(0.0)), np.float32)
        g = grid_arrays(GridBuilder(GridParams()).build(tris), tris)
        for view in views:
            label, nc, nt, ns = measure(sc, g, view, a.size, a.runs)
            rows.append([label, f"{nc:.1f}, {nt:.1f}", f"{ns:.0f}"])
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
