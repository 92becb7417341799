"""BENCHMARKS.md section 13, "Camera rays through `RayCaster.cast`, by the order of the rays":
Mrays/s of ``RayCaster.cast`` on the ``bench peers`` camera rays of each scene and view, one
thread, in three orders: row order as the camera makes them (the caster recognises the image and
takes it in 8x8 tiles), pre-sorted into 8x8 tiles by the caller, and shuffled.

    .venv/bin/python scripts/cast_ray_order.py

makes the table (1024x1024 rays, the best of 4 timed casts after an untimed one); ``--size 64
--runs 1`` is a quick check.  The caster is ``RayCaster.from_triangles`` over the scene at t = 0
with ``GridParams()`` (a uniform grid), cast with its defaults (nearest hit, watertight, packets,
float64) and ``threads=1``; the rays are those of ``bench peers`` (:mod:`gridrt.app.bench.peers`):
the scene's camera ("frame") or that camera moved in until the scene fills the view ("fill").
The tile order is :func:`gridrt.trace.batch.tile_order`'s; the shuffle a fixed-seed permutation.
"""

import argparse

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.api import RayCaster
from gridrt.app.bench.output import md_table
from gridrt.app.bench.peers import peer_rays
from gridrt.app.bench.scenes import resolve_scene
from gridrt.app.bench.stats import timings
from gridrt.config import GridParams
from gridrt.trace.batch import tile_order

from tables import add_out_option, add_ray_options, items, keep_output, print_settings, scene_label

#: the table's scenes and views (section 13: ``bench peers``' scenes and its camera views)
SCENES = "cesium,lucy:twist,icosphere:1310720:twist"
VIEWS = "fill,frame"
SIZE, RUNS = 1024, 4
#: what the script does not let an option change
FIXED = ("RayCaster.from_triangles(the scene at t = 0, GridParams()).cast(o, d, threads=1); "
         "the best of the timed casts after one untimed cast")
HEADER = ["scene, view", "row order (tiles recognised)", "pre-sorted into 8x8 tiles by the caller", "shuffled"]
#: seed of the shuffled order
SEED = 20261202


def orders(n, width):
    """The three orders of n rays of a ``width``-wide image, as index arrays: row order, 8x8
    tiles, shuffled."""
    tiles = np.empty(n, np.int64)
    tile_order(n, width, 0, tiles)
    return [np.arange(n), tiles, np.random.default_rng(SEED).permutation(n)]


def measure(caster, o, d, idx, runs):
    """Mrays/s of the best of ``runs`` one-thread casts of the rays in the order idx (after one
    untimed cast)."""
    oi, di = np.ascontiguousarray(o[idx]), np.ascontiguousarray(d[idx])
    _median, best, _worst = timings(lambda: caster.cast(oi, di, threads=1), runs)
    return len(idx) / (best * 1e3)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_ray_options(p, SCENES, VIEWS, SIZE, RUNS, "camera views", "timed casts")
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
        for view in views:
            origin, _cam, _o32, _d32, o, d = peer_rays(sc, a.size, view)
            caster = RayCaster.from_triangles(sc.scene.triangles_at(0.0, origin=origin), GridParams())
            mrays = [measure(caster, o, d, idx, a.runs) for idx in orders(len(o), a.size)]
            rows.append([f"{scene_label(text, len(caster.triangles))}, {view}", *(f"{m:.2f}" for m in mrays)])
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
