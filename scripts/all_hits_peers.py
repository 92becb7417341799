"""Every hit along a ray against Open3D's RaycastingScene: BENCHMARKS.md section 18, table "mesh |
triangles | rays | hits a ray | gridrt count_hits | gridrt all_hits | Open3D count_intersections |
Open3D list_intersections | counts agree" (ms a batch).

    .venv/bin/python scripts/all_hits_peers.py

Per mesh (unit icospheres of about --sizes triangles), ``--rays`` rays from uniform origins in
[-2, 2]^3 towards uniform points of [-0.5, 0.5]^3 (seeded), the same float32-representable rays
for both sides; gridrt's RayCaster (``--threads`` threads) and Open3D's RaycastingScene (Embree
inside; Open3D picks its own thread count: all cores) each run every query once untimed, then
``--runs`` times; a cell is the median.  "counts agree" is the fraction of rays whose counts are
equal.  Without Open3D (``pip install open3d-cpu``; it needs libusb-1.0 on Linux) its columns say
n/a.
"""

import argparse
import time

import numpy as np

import gridrt
from gridrt.app.bench.output import md_table
from gridrt.config import GridParams
from gridrt.scene import icosphere_mesh
from tables import add_out_option, items, scene_label, start

SIZES = "20480,327680"
DEFAULTS = dict(rays=200000, runs=5, threads=2)
HEADER = ["mesh", "triangles", "rays", "hits a ray", "gridrt count_hits", "gridrt all_hits",
          "Open3D count_intersections", "Open3D list_intersections", "counts agree"]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", default=SIZES, help=f"icosphere triangle counts, comma-separated (default: the table's, {SIZES})")
    p.add_argument("--rays", type=int, default=DEFAULTS["rays"], help="rays a batch (default: the table's, 200000)")
    p.add_argument("--runs", type=int, default=DEFAULTS["runs"], help="timed runs a cell, the median kept (default: the table's, 5)")
    p.add_argument("--threads", type=int, default=DEFAULTS["threads"], help="gridrt's threads (default: the table's, 2)")
    add_out_option(p)
    return start(p, argv)


def _open3d():
    try:
        import open3d as o3d  # deferred: an optional peer, loaded only by this script's run
    except (ImportError, OSError):   # not installed, or installed without the libraries it loads
        return None
    return o3d


def median_ms(f, runs):
    f()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def main(argv=None):
    a = parse_args(argv)
    o3d = _open3d()
    rows = []
    for n in (int(x) for x in items(a.sizes)):
        m = icosphere_mesh(n)
        rng = np.random.default_rng(0)
        O = rng.uniform(-2, 2, (a.rays, 3)).astype(np.float32).astype(np.float64)
        D = (rng.uniform(-0.5, 0.5, (a.rays, 3)) - O).astype(np.float32).astype(np.float64)
        caster = gridrt.RayCaster(m.vertices, m.faces, GridParams(threads=a.threads))
        counts = caster.count_hits(O, D)
        cells = [f"{median_ms(lambda: caster.count_hits(O, D), a.runs):.0f}",
                 f"{median_ms(lambda: caster.all_hits(O, D), a.runs):.0f}"]
        agree = "n/a"
        if o3d is not None:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(m.vertices.astype(np.float32), m.faces.astype(np.uint32))
            R = o3d.core.Tensor(np.hstack([O, D]).astype(np.float32))
            cells += [f"{median_ms(lambda: scene.count_intersections(R), a.runs):.0f}",
                      f"{median_ms(lambda: scene.list_intersections(R), a.runs):.0f}"]
            agree = f"{np.mean(scene.count_intersections(R).numpy() == counts):.4f}"
        else:
            cells += ["n/a", "n/a"]
        rows.append([scene_label("icosphere", len(m.faces)), f"{len(m.faces):,}", f"{a.rays:,}",
                     f"{counts.mean():.2f}", *cells, agree])
        print(f"# icosphere {len(m.faces)} done", flush=True)
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
