"""Every hit along a ray against Open3D's RaycastingScene and trimesh over embreex: BENCHMARKS.md
section 18, table "mesh | rays | hits a ray | gridrt count_hits | gridrt all_hits | Open3D
count_intersections | Open3D list_intersections | trimesh + embreex | even counts: gridrt, Open3D,
trimesh | counts agree: Open3D, trimesh" (ms a batch).

    .venv/bin/python scripts/all_hits_peers.py

Per mesh (unit icospheres of about --sizes triangles), two sets of ``--rays`` rays, the same
float32-representable rays for every side, from uniform origins on the sphere of radius 3: "random",
towards uniform points of [-0.5, 0.5]^3, and "at vertices", towards the mesh's vertices (the
direction rounded to float32, so each ray passes within rounding of a vertex; seeded).  gridrt's RayCaster (``--threads`` threads),
Open3D's RaycastingScene (Embree inside; Open3D picks its own thread count: all cores) and
trimesh's embreex intersector (``intersects_location(..., multiple_hits=True)``, the every-hit
query trimesh users have: it casts again from beyond each hit) each run every query once untimed,
then ``--runs`` times; a cell is the median.  Every ray starts outside the closed mesh, so its
crossings pair up: "even counts" is the fraction of rays each side counts an even number of
crossings for (the right answer is 1), "counts agree" the fraction whose counts equal gridrt's.
Without Open3D (``pip install open3d-cpu``; it needs libusb-1.0 on Linux) or embreex (the peers
extra) their columns say n/a.
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
HEADER = ["mesh", "rays", "hits a ray", "gridrt count_hits", "gridrt all_hits", "Open3D count_intersections",
          "Open3D list_intersections", "trimesh + embreex", "even counts: gridrt, Open3D, trimesh",
          "counts agree: Open3D, trimesh"]


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


def _trimesh_embreex(V, F):
    try:
        import trimesh  # deferred: optional peers, loaded only by this script's run
        from trimesh.ray.ray_pyembree import RayMeshIntersector  # deferred: as trimesh
        return RayMeshIntersector(trimesh.Trimesh(V, F, process=False))
    except (ImportError, OSError):
        return None


def ray_sets(m, n):
    """{"random": (O, D), "at vertices": (O, D)} of n float32-representable float64 rays each."""
    rng = np.random.default_rng(0)
    f32 = lambda a: a.astype(np.float32).astype(np.float64)
    outside = lambda: f32(3.0 * (u := rng.normal(size=(n, 3))) / np.linalg.norm(u, axis=1, keepdims=True))
    O = outside()
    sets = {"random": (O, f32(rng.uniform(-0.5, 0.5, (n, 3)) - O))}
    O = outside()
    sets["at vertices"] = (O, f32(m.vertices[rng.integers(0, len(m.vertices), n)]) - O)
    return sets


def fraction(x):
    return f"{np.mean(x):.4f}"


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
        caster = gridrt.RayCaster(m.vertices, m.faces, GridParams(threads=a.threads))
        scene = None
        if o3d is not None:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(m.vertices.astype(np.float32), m.faces.astype(np.uint32))
        tm = _trimesh_embreex(m.vertices.astype(np.float32).astype(np.float64), m.faces)
        for kind, (O, D) in ray_sets(m, a.rays).items():
            counts = caster.count_hits(O, D)
            cells = [f"{median_ms(lambda: caster.count_hits(O, D), a.runs):.0f}",
                     f"{median_ms(lambda: caster.all_hits(O, D), a.runs):.0f}"]
            even, agree = [fraction(counts % 2 == 0)], []
            if scene is not None:
                R = o3d.core.Tensor(np.hstack([O, D]).astype(np.float32))
                cells += [f"{median_ms(lambda: scene.count_intersections(R), a.runs):.0f}",
                          f"{median_ms(lambda: scene.list_intersections(R), a.runs):.0f}"]
                theirs = scene.count_intersections(R).numpy()
                even.append(fraction(theirs % 2 == 0))
                agree.append(fraction(theirs == counts))
            else:
                cells += ["n/a", "n/a"]
                even.append("n/a")
                agree.append("n/a")
            if tm is not None:
                hits = lambda: tm.intersects_location(O, D, multiple_hits=True)
                cells.append(f"{median_ms(hits, a.runs):.0f}")
                theirs = np.bincount(hits()[1], minlength=len(O))
                even.append(fraction(theirs % 2 == 0))
                agree.append(fraction(theirs == counts))
            else:
                cells.append("n/a")
                even.append("n/a")
                agree.append("n/a")
            rows.append([scene_label("icosphere", len(m.faces)), f"{a.rays:,} {kind}", f"{counts.mean():.2f}", *cells,
                         ", ".join(even), ", ".join(agree)])
        print(f"# icosphere {len(m.faces)} done", flush=True)
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
