"""``gridrt bench``: benchmarks.  Every figure is a median of several runs after a warm-up run
(numba compiles on the first call), with min and max, thread count, scene and resolution.

* ``core``: serial grid build (bbox and exact insertion) and primary-ray throughput at 1 and 2
  threads on a ~100k and a ~1M triangle mesh.
"""

import csv
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

import engine  # noqa: F401
from engine.camera import Camera
from engine.config import GridParams, RenderParams
from engine.grid.build import GridBuilder
from engine.trace.render import Renderer

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def add_parser(sub):
    p = sub.add_parser("bench", help="benchmarks (medians after warm-up)")
    bsub = p.add_subparsers(dest="bench", required=True)
    c = bsub.add_parser("core", help="serial build ms and primary-ray Mrays/s on ~100k and ~1M triangles")
    c.add_argument("--runs", type=int, default=5, help="timed runs per figure (median reported)")
    c.add_argument("--size", type=int, default=1024, help="square image edge for the ray figures")
    c.add_argument("--scenes", default=None,
                   help="comma-separated: lucy, bunny16 (bunny subdivided to 1.1M), ico82k, ico1m, or mesh paths")
    c.add_argument("--out", type=Path, default=Path("out/bench_core"), help="folder for core.csv")
    c.set_defaults(func=run_core)
    return p


def machine_info():
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import numba

    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "numba": numba.__version__,
            "threading_layer": os.environ.get("NUMBA_THREADING_LAYER", "")}


def timings(fn, runs):
    fn()  # warm-up (compiles on a cold cache)
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(ts)), float(np.min(ts)), float(np.max(ts))


def subdivide(tris, times):
    """Split every triangle into 4 (edge midpoints), ``times`` times: F -> F * 4**times."""
    t = tris.astype(np.float64)
    for _ in range(times):
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        t = np.concatenate([np.stack(x, 1) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return np.ascontiguousarray(t, np.float32)


def core_scene(name):
    from engine.scene import icosphere_mesh, load_mesh

    if name == "lucy":
        m = load_mesh(DATA / "static" / "lucy" / "Lucy100k.ply")
        return "Lucy100k", m.triangles()
    if name == "bunny16":
        m = load_mesh(DATA / "static" / "stanford_bunny" / "stanford-bunny.obj")
        return "bunny x16", subdivide(m.triangles(), 2)
    if name == "ico82k":
        return "icosphere 82k", icosphere_mesh(81920).triangles()
    if name == "ico1m":
        return "icosphere 1.3M", icosphere_mesh(1310720).triangles()
    m = load_mesh(name)
    return m.name, m.triangles()


def facing_camera(lo, hi, fov=45.0):
    """Look along the box's thinnest axis (slightly tilted) so the mesh fills the view."""
    ext = hi - lo
    a = int(np.argmin(ext))
    d = np.full(3, 0.15)
    d[a] = 1.0
    up = (0.0, 1.0, 0.0) if a != 1 else (0.0, 0.0, 1.0)
    big = float(np.sort(ext)[1:].max())
    dist = 0.5 * big / math.tan(math.radians(fov) / 2) * 1.05 + 0.5 * ext[a]
    c = 0.5 * (lo + hi)
    d = d / np.linalg.norm(d)
    return Camera(eye=tuple(c + d * dist), target=tuple(c), up=up, fov=fov)


def run_core(a):
    if a.runs < 1:
        raise engine.InputError("--runs must be at least 1")
    if a.scenes:
        names = [s.strip() for s in a.scenes.split(",") if s.strip()]
    elif DATA.exists():
        names = ["lucy", "bunny16"]
    else:
        print(f"note: {DATA} not found; using built-in icospheres", file=sys.stderr)
        names = ["ico82k", "ico1m"]
    info = machine_info()
    print(f"machine: {info['cpu']}, {info['cores']} cores, numba {info['numba']}, numpy {info['numpy']}")
    rows = []
    steps = len(names) * 4
    bar = tqdm(total=steps, desc="bench core", file=sys.stderr)
    for name in names:
        label, tris = core_scene(name)
        for ins in ("bbox", "exact"):
            b = GridBuilder(GridParams(strategy="serial", insert=ins, threads=1))
            med, lo_, hi_ = timings(lambda: b.build(tris), a.runs)
            g = b.build(tris)
            rows.append(dict(scene=label, triangles=len(tris), what=f"serial build {ins}", threads=1,
                             median_ms=med, min_ms=lo_, max_ms=hi_, refs_per_tri=g.references / len(tris),
                             cells=g.spec.n_cells, mrays=""))
            bar.update()
        g = GridBuilder(GridParams(strategy="serial", threads=1)).build(tris)
        cam = facing_camera(g.spec.lo, g.spec.hi)
        for th in (1, 2):
            r = Renderer()
            rp = RenderParams(a.size, a.size, threads=th)
            med, lo_, hi_ = timings(lambda: r.render(g, tris, cam, rp), a.runs)
            res = r.render(g, tris, cam, rp)
            rows.append(dict(scene=label, triangles=len(tris), what=f"primary rays {a.size}x{a.size}", threads=th,
                             median_ms=med, min_ms=lo_, max_ms=hi_, refs_per_tri=g.references / len(tris),
                             cells=g.spec.n_cells, mrays=a.size * a.size / med / 1e3,
                             hit_fraction=res.stats["hit_fraction"], tests_per_ray=res.stats["tests_per_ray"]))
            bar.update()
    bar.close()
    a.out.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(a.out / "core.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print(f"{'scene':16s} {'tris':>9s} {'what':28s} {'thr':>3s} {'median ms':>10s} {'min':>8s} {'max':>8s} "
          f"{'refs/tri':>8s} {'Mrays/s':>8s}")
    for r in rows:
        mr = f"{r['mrays']:.2f}" if r["mrays"] != "" else ""
        print(f"{r['scene']:16s} {r['triangles']:9d} {r['what']:28s} {r['threads']:3d} {r['median_ms']:10.2f} "
              f"{r['min_ms']:8.2f} {r['max_ms']:8.2f} {r['refs_per_tri']:8.2f} {mr:>8s}"
              + (f"  (hit fraction {r['hit_fraction']:.2f})" if "hit_fraction" in r else ""))
    print(f"medians of {a.runs} runs after 1 warm-up; wrote {a.out / 'core.csv'}")
    return 0
