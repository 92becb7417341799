"""Rays taken in the order of their origins, for count_hits and contains on large meshes:
BENCHMARKS.md section 18, table "mesh | points | threads | as given ms | in origin order ms | in
origin order / as given".

    .venv/bin/python scripts/contains_order.py

Per unit icosphere of about each of ``--sizes`` triangles and each count of ``--points`` points
drawn uniformly in [-1.1, 1.1]^3 (seeded), ``RayCaster.contains`` (a ray a point, in one fixed
direction, through the all-hits walk) on ``--threads`` threads, once with the batch walked as
given and once in the order of its rays' origins along a Morton curve (``gridrt.trace.all_hits
.ORDER_RAYS`` and ``ORDER_TRIANGLES`` set to take every batch that way or none), the two in
turns: one untimed round, then ``--runs`` rounds, medians.  The verdicts are the same either way
(checked on every point).  The engine's own thresholds decide which batches are ordered; this
script overrides them to time both ways on the same batch.
"""

import argparse
import time

import numpy as np

import gridrt
import gridrt.trace.all_hits as ah
from gridrt.app.bench.affinity import Affinity
from gridrt.scene import icosphere_mesh
from tables import add_out_option, items, print_table, scene_label, start

SIZES = "1310720,5242880"
HEADER = ["mesh", "points", "threads", "as given ms", "in origin order ms", "in origin order / as given"]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", default=SIZES, help="icosphere triangle counts (default: the table's, %(default)s)")
    p.add_argument("--points", default="50000,200000,800000",
                   help="points a batch (default: the table's, %(default)s)")
    p.add_argument("--threads", default="1,2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=3, help="timed rounds, the median kept (default: the table's, 3)")
    add_out_option(p)
    return start(p, argv)


def ordered(on):
    """Every batch walked in origin order (on) or none."""
    ah.ORDER_RAYS, ah.ORDER_TRIANGLES = (1, 1) if on else (1 << 62, 1 << 62)


def measure(a):
    rows = []
    keep = ah.ORDER_RAYS, ah.ORDER_TRIANGLES
    try:
        for size in (int(s) for s in items(a.sizes)):
            m = icosphere_mesh(size)
            label = scene_label("icosphere", len(m.faces))
            for T in (int(t) for t in items(a.threads)):
                caster = gridrt.RayCaster(m.vertices, m.faces, gridrt.GridParams(threads=T))
                for n in (int(p) for p in items(a.points)):
                    P = np.random.default_rng(0).uniform(-1.1, 1.1, (n, 3))
                    ms, got = {False: [], True: []}, {}
                    with Affinity(T):
                        for r in range(1 + a.runs):
                            for on in (False, True):
                                ordered(on)
                                t0 = time.perf_counter()
                                got[on] = caster.contains(P, threads=T)
                                if r:
                                    ms[on].append((time.perf_counter() - t0) * 1e3)
                    if not np.array_equal(got[False], got[True]):
                        raise SystemExit(f"{label}, {n} points: the verdicts differ between the two orders")
                    given, sorted_ = np.median(ms[False]), np.median(ms[True])
                    rows.append([label, f"{n:,}", str(T), f"{given:.0f}", f"{sorted_:.0f}", f"{sorted_ / given:.2f}"])
                    print(f"# {label} {n} points T={T}: {given:.0f} ms as given, {sorted_:.0f} ms in origin order",
                          flush=True)
    finally:
        ah.ORDER_RAYS, ah.ORDER_TRIANGLES = keep
    return rows


def main(argv=None):
    return print_table(HEADER, measure, parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
