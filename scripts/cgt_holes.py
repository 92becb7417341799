"""BENCHMARKS.md section 6, "Holes through the packet traversal (CGT)": the soak's probes of the
packet traversal on the closed real meshes, counted into a table.

    .venv/bin/python scripts/cgt_holes.py

traces at least 10M probe rays as packets and 10M camera-row rays on each mesh (``--rays 100000``
is a quick check).  The probes and the hole criterion are the test suite's
(tests/helpers/watertight.py, as tests/test_soak.py runs them under ``-m soak``): star packets of
up to 8x8 rays from one eye in front of every face touching the target, aimed at a vertex, its
one-ring and points along its spokes and link edges, traced by the packet kernel; and camera rows
(``Renderer.render``, CGT, 512x1 images whose plane holds a shared edge).  A hole is a miss, or a
hit beyond the target (relative 1e-6; in float32 1e-5, where a hit beyond it on a triangle facing
the eye is not counted).  The counts are checked as the soak test checks them: a watertight hole
fails the script.  Nothing here is timed.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

TESTS_DIR = Path(__file__).resolve().parents[1] / "tests"
sys.path.insert(0, str(TESTS_DIR))  # the probes are the test suite's: tests/helpers/watertight.py

from conftest import ARMADILLO, available, load_mesh_arrays  # noqa: E402
from gridrt.app.bench.output import md_table  # noqa: E402
from gridrt.config import GridParams  # noqa: E402
from gridrt.grid import GridBuilder  # noqa: E402
from helpers.watertight import ProbeMesh, cgt_counts, cgt_report  # noqa: E402

from tables import add_out_option, start  # noqa: E402

MESHES = {ARMADILLO: "Armadillo", "static/stanford_dragon/dragon.obj": "dragon", "static/lucy/Lucy100k.ply": "Lucy"}
BATCH = 200_000
HEADER = ["mesh", "packet probes", "watertight holes", "float32 watertight holes", "fast-test holes (rate)",
          "camera-row rays", "watertight holes", "float32 watertight holes", "fast-test holes (rate)"]


def probe(relpath, n_rays, rng):
    """(packet counts, camera-row counts, seconds) of at least n_rays packet rays and n_rays
    camera-row rays on one mesh."""
    m = ProbeMesh(*load_mesh_arrays(relpath))
    grid = GridBuilder(GridParams(threads=2, density=4.0)).build(m.tris)
    t0 = time.perf_counter()
    pk, rows = cgt_counts(m, grid, rng, n_rays, n_rays, BATCH)
    return m, pk, rows, time.perf_counter() - t0


def rate(holes, n):
    return f"{holes:,} ({100 * holes / n:.2f}%)"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rays", type=int, default=10_000_000,
                   help="packet rays and camera-row rays per mesh, each (default: the table's, %(default)s)")
    add_out_option(p)
    a = start(p, argv)
    print()
    rng = np.random.default_rng(2024)
    table = []
    for relpath in available(*MESHES):
        m, pk, rows, secs = probe(relpath, a.rays, rng)
        cgt_report(MESHES[relpath], pk, rows, secs)  # prints the counts; raises on a watertight hole
        n_pk, n_rows = pk["probes"], rows["rays"]
        table.append([f"{MESHES[relpath]} ({len(m.tris):,})", f"{n_pk:,}", f"{int(pk['wt_holes'].sum()):,}",
                      f"{int(pk['wt32_holes'].sum()):,}", rate(int(pk["fast_holes"].sum()), n_pk), f"{n_rows:,}",
                      f"{rows['wt_holes']:,}", f"{rows['wt32_holes']:,}", rate(rows["fast_holes"], n_rows)])
    print()
    print("\n".join(md_table(HEADER, table)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
