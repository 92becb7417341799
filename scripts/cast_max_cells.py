"""Batch casts against MAX_CELLS: BENCHMARKS.md section 11, table "scene, rays | single rays (0) |
16 | 32 | 64 | 128 | Embree" (Mrays/s at 1 / 2 threads).

    .venv/bin/python scripts/cast_max_cells.py

For each scene, the ``bench peers`` rays (gridrt.app.bench.peers: size x size rays of the "fill"
view in image order, the same rays shuffled, and as many random rays from inside the scene's
bounds) are cast through one grid of the scene at t = 0 (engine-default GridParams) with
``gridrt.trace.render.cast_batch(..., max_cells=N)`` for each N (0: every ray singly), and by
Embree (embreex, robust scene flag, where installed) in a pool of as many threads, the process
pinned to that many CPUs as ``bench peers`` pins it.  Each cell is the median of ``--runs`` timed
casts after one untimed one.
"""

import argparse
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.affinity import Affinity
from gridrt.app.bench.peers import peer_rays
from gridrt.app.bench.scenes import resolve_scene
from gridrt.app.bench.sides import EmbreeRobustSide, MissingPeer
from gridrt.app.bench.stats import timings
from gridrt.config import GridParams
from gridrt.grid.build import GridBuilder
from gridrt.trace.render import cast_batch
from tables import add_out_option, keep_output

#: the table's scenes, and their labels in it
SCENES = {"icosphere:81920:twist": "icosphere 82k twisted", "icosphere:1310720:twist": "icosphere 1.3M twisted"}
MAX_CELLS = (0, 16, 32, 64, 128)
DEFAULTS = dict(size=512, runs=3, threads="1,2")


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=DEFAULTS["size"], help="size x size rays (default: the table's, 512)")
    p.add_argument("--runs", type=int, default=DEFAULTS["runs"], help="timed casts a cell, after one untimed (default: the table's, 3)")
    p.add_argument("--threads", default=DEFAULTS["threads"], help="thread counts, comma-separated (default: the table's, 1,2)")
    add_out_option(p)
    return p.parse_args()


def row_labels(label, first):
    """The table's labels of one scene's three rows (the first scene's random rows say where from)."""
    rand = "random rays from inside the bounds" if first else "random rays"
    return {"fill": f"{label}, fill camera, in order", "shuffled": "the same rays shuffled", "random": rand}


def ray_sets(sc, size):
    """{row: (float32 origins, float32 dirs, float64 origins, float64 dirs)} and the fill view's frame origin."""
    origin, _, o32, d32, o, d = peer_rays(sc, size, "fill")
    perm = np.random.default_rng(1).permutation(len(o))
    sets = {"fill": (o32, d32, o, d),
            "shuffled": tuple(np.ascontiguousarray(x[perm]) for x in (o32, d32, o, d))}
    r_origin, _, *rnd = peer_rays(sc, size, "random")
    assert np.array_equal(r_origin, origin)  # (one frame for every ray set: one grid)
    sets["random"] = tuple(rnd)
    return origin, sets


def mrays(n, ms):
    return n / ms / 1e3


def main():
    a = parse_args()
    keep_output(a.out)
    threads = [int(x) for x in a.threads.split(",") if x.strip()]
    for name in ("size", "runs", "threads"):
        given = getattr(a, name) != DEFAULTS[name]
        print(f"# {name}: {getattr(a, name)} ({'--' + name if given else 'default, the table'}'s)")
    print(f"# scenes: {', '.join(SCENES)} (the table's); max_cells: {', '.join(map(str, MAX_CELLS))} (the table's)")
    try:
        emb = EmbreeRobustSide()
        print(f"# Embree: {emb.version}, robust scene flag")
    except MissingPeer as e:
        emb = None
        print(f"# Embree: not measured ({e})")
    rows = []
    for k, (spec, label) in enumerate(SCENES.items()):
        sc = resolve_scene(spec)
        origin, sets = ray_sets(sc, a.size)
        tris = np.ascontiguousarray(sc.scene.triangles_at(0.0, origin=origin), np.float32)
        grid = GridBuilder(GridParams()).build(tris)
        if emb is not None:
            emb.build(tris)
        cells = {}
        for T in threads:
            with Affinity(T), ThreadPoolExecutor(T) as pool:
                for key, (o32, d32, o, d) in sets.items():
                    for N in MAX_CELLS:
                        ms = timings(lambda: cast_batch(grid, tris, o, d, threads=T, max_cells=N), a.runs)[0]
                        cells.setdefault((key, N), []).append(mrays(len(o), ms))
                    if emb is not None:
                        ms = timings(lambda: emb.cast(pool, o32, d32, T), a.runs)[0]
                        cells.setdefault((key, "embree"), []).append(mrays(len(o), ms))
        for key, text in row_labels(label, k == 0).items():
            vals = [" / ".join(f"{x:.2f}" for x in cells[(key, N)]) for N in MAX_CELLS]
            vals.append(" / ".join(f"{x:.2f}" for x in cells[(key, "embree")]) if emb is not None else "n/a")
            rows.append([text, *vals])
    print()
    print("| scene, rays | single rays (0) | 16 | 32 | 64 | 128 | Embree |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
