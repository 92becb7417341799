"""Hard shadows of point lights, the casts alone: BENCHMARKS.md section 15, table "scene | triangles
| lights | shadow rays | threads | gridrt Mrays/s | embreex occluded Mrays/s | native Mrays/s |
native robust Mrays/s | gridrt / embreex | gridrt / native | differ from single rays | brute force
checked | differ from brute force | differ from native, native robust".

    .venv/bin/python scripts/shadow_rays.py

For each scene, one frame is rendered with ``material`` shading and hard shadows of every light
(the CGT traversal; the kitchen through its own camera at SIZE x 3/4 SIZE, t = 5; the meshes from
the fill view, their camera moved in until the mesh fills the SIZE x SIZE frame, lit by the default
light; SIZE 1024), and every batch of shadow segments the material pass hands to the batch caster is kept
(``gridrt.trace.batch.cast_grouped``: the grid, the segments from the light's end back to the hit,
t in (0, 1), any hit, the pass's own settings; the renderer makes no light maps, so every segment
is cast).  Then, at each thread count, the same batches are
cast again, ``--runs`` times after ``--warmup``: Mrays/s is the segments of all batches over the
median time of a round (the casts alone: no shading, no segment making).

Exact: the blocked flags equal those of the same segments cast one ray at a time (the single-ray
DDA, ``max_cells`` 0: one ray per light per pixel, what the renderer's exact mode means), counted
over every segment, and those of a float64 brute force over every triangle of the batch's grid on
``--check`` segments drawn at random (seed 1), counted where both are clear of rounding (the brute
force finds no crossing, or its nearest crossing lies within (1e-9, 1 - 1e-9) and more than 1e-9
inside its triangle's edges: at an edge or an end point, float32 and float64 arithmetic may judge
a ray differently).  embreex (robust scene, ``query='OCCLUDED'``, float32 segments, tfar 1) casts the
same segments over the same triangles, in chunks spread over a pool of the thread count's Python
threads, timed alike.  Native Embree 3 (C++, gridrt.app.bench.occluded: ``rtcOccluded1``,
``rtcOccluded16`` packets and ``rtcOccluded1M`` streams of the same segments in groups of 64 in
the same order, each batch against its grid's triangles, on the thread count's pinned threads;
default build quality) casts them too, with default scene flags and with the robust flag: each
column is its fastest mode's median round (the mode in brackets), ``--runs`` after ``--warmup``.
The segments on which gridrt and native robust disagree (at most 256 a row) are checked against the
float64 brute force (printed: where it is clear of rounding, which side it agrees with).
"""

import argparse
import concurrent.futures
import importlib
import tempfile

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.affinity import Affinity
from gridrt.app.bench.looks import looks_spec
from gridrt.app.bench import occluded as native_occluded
from gridrt.app.bench.native import _bary_min
from gridrt.app.bench.output import md_table
from gridrt.app.bench.reference import brute_cast
from gridrt.app.bench.scenes import camera_rays, resolve_scene
from gridrt.app.bench.sides import EmbreeSide, MissingPeer
from gridrt.app.bench.stats import timings
from gridrt.config import GridParams, RenderParams
from gridrt.grid.build import build_grid
from gridrt.pipeline import FramePipeline
from gridrt.threads import use_threads
from gridrt.trace.lightmap import NoLightMaps
from gridrt.trace.twin import TWINS, parallel_first
from tables import add_out_option, items, start

#: the module whose cast_grouped the material pass calls (gridrt.trace names its render function
#: render, so the module is imported by its full name)
RENDER = importlib.import_module("gridrt.trace.render")
SCENES = "kitchen,icosphere:20480:twist,lucy:twist,icosphere:1310720:twist"
HEADER = ["scene", "triangles", "lights", "shadow rays", "threads", "gridrt Mrays/s", "embreex occluded Mrays/s",
          "native Mrays/s", "native robust Mrays/s", "gridrt / embreex", "gridrt / native", "differ from single rays",
          "brute force checked", "differ from brute force", "differ from native, native robust"]
#: disagreements with native robust checked against the brute force, at most, a row
NATIVE_CHECK = 256
#: clear of rounding: t and the barycentric margin (see the docstring)
CLEAR = 1e-9


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default=SCENES, help="comma-separated scenes: kitchen (its own camera, SIZE x 3/4 "
                   "SIZE) or bench scene specs of meshes (fill view, SIZE x SIZE) (default: the table's, %(default)s)")
    p.add_argument("--size", type=int, default=1024, help="image edge (default: the table's, %(default)s)")
    p.add_argument("--threads", default="1,2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=5, help="timed rounds, the median kept (default: the table's, 5)")
    p.add_argument("--warmup", type=int, default=1, help="untimed rounds first (default: the table's, 1)")
    p.add_argument("--check", type=int, default=2000,
                   help="segments checked against the float64 brute force (default: the table's, 2000)")
    p.add_argument("--native-bin", default=str(native_occluded.DEFAULT_BIN),
                   help="the native occlusion tool, compiled there from gridrt/app/bench/occluded.cpp when missing "
                        "(default %(default)s)")
    add_out_option(p)
    return start(p, argv)


class Spy:
    """Keeps the batches of shadow segments the material pass casts (copies of the arrays)."""

    def __init__(self):
        self.calls = []
        self.cast = RENDER.cast_grouped

    def __enter__(self):
        def spy(g, o, d, tmin, tmax, watertight, any_hit, out, max_cells, f32, tri_only=False, rows=None,
                sorted_max_cells=None):
            kept = (o.copy(), d.copy()) if rows is None else (o[rows], d[rows])
            self.calls.append((g, *kept, (tmin, tmax, watertight, any_hit), (max_cells, sorted_max_cells), f32,
                               tri_only))
            return self.cast(g, o, d, tmin, tmax, watertight, any_hit, out, max_cells, f32, tri_only=tri_only,
                             rows=rows, sorted_max_cells=sorted_max_cells)
        RENDER.cast_grouped = spy
        return self

    def __exit__(self, *exc):
        RENDER.cast_grouped = self.cast


def segments(name, size):
    """(label, triangles, lights, the kept batches) of one scene's frame."""
    sc = resolve_scene(name)
    if name == "kitchen":
        spec = looks_spec(sc.spec, size, 2, "cgt", "material", True).resized(size, size * 3 // 4)
        pipe = FramePipeline.from_spec(spec, sc.scene)
        pipe.renderer._lightmaps = NoLightMaps()   # (every segment cast: no light maps)
        pipe.step(5.0)
        with Spy() as spy:
            st = pipe.step(5.0).stats
        return sc.label, int(st["triangles"]), int(st["lights"]), spy.calls
    origin, cam, _, _, _, _ = camera_rays(sc, size, fill=True)
    tris = np.asarray(sc.scene.triangles_at(0.0, origin=origin), np.float32)
    grid = build_grid(tris, GridParams(threads=2), origin=np.zeros(3))
    rp = RenderParams(width=size, height=size, shading="material", shadows=True, traversal="cgt", threads=2)
    r = RENDER.Renderer()
    r._lightmaps = NoLightMaps()
    r.render(grid, tris, cam, rp)
    with Spy() as spy:
        st = r.render(grid, tris, cam, rp).stats
    return sc.label, len(tris), int(st["lights"]), spy.calls


def outputs(calls):
    """Output buffers for every kept batch, kept from round to round as the renderer keeps its own."""
    return [(np.empty(len(o)), np.empty(len(o), np.int32), np.empty(len(o)), np.empty(len(o))) for _, o, *_ in calls]


def cast_all(calls, outs, max_cells=None):
    """Cast every kept batch again into its buffers of outs (with its own max_cells, or this one)."""
    for (g, o, d, q, mc, f32, tri_only), out in zip(calls, outs):
        if max_cells is None:
            RENDER.cast_grouped(g, o, d, *q, out, mc[0], f32, tri_only=tri_only, sorted_max_cells=mc[1])
        else:
            RENDER.cast_grouped(g, o, d, *q, out, max_cells, f32, tri_only=tri_only)


def blocked_of(outs):
    """The blocked flags of every kept batch's buffers, joined."""
    return np.concatenate([out[1] >= 0 for out in outs])


class Occluded:
    """An embreex scene (robust) over each kept batch's grid triangles (one per grid), and the
    batches' segments in float32."""

    def __init__(self, calls):
        sides = {}
        self.jobs = []
        for g, o, d, *_ in calls:
            if id(g.tris) not in sides:
                sides[id(g.tris)] = EmbreeSide(robust=True)
                sides[id(g.tris)].build(np.ascontiguousarray(g.tris, np.float32))  # (the BVH, untimed)
            self.jobs.append((sides[id(g.tris)], np.ascontiguousarray(o, np.float32),
                              np.ascontiguousarray(d, np.float32)))

    def cast(self, pool, threads):
        """Every batch's occlusion casts: their chunks (EmbreeSide.occluded)."""
        return [side.occluded(pool, o, d, threads) for side, o, d in self.jobs]

    @staticmethod
    def blocked(parts):
        """The blocked flags of :meth:`cast`'s chunks, joined."""
        return np.concatenate([EmbreeSide.blocked(p) for p in parts])


class Native:
    """The kept batches in the native occlusion tool's folder (one mesh a grid, in the order the
    batches first use them)."""

    def __init__(self, calls, binary, folder):
        self.binary, self.folder = binary, folder
        meshes, batches = {}, []
        for g, o, d, *_ in calls:
            m = meshes.setdefault(id(g.tris), (len(meshes), g.tris))[0]
            batches.append((m, o, d))
        native_occluded.write_folder(folder, [t for _, t in meshes.values()], batches)

    def best(self, threads, runs, warmup, robust):
        """(median ms of a round, mode, verdicts) of the fastest mode."""
        res = native_occluded.cast(self.binary, self.folder, threads, runs, warmup, robust=robust, verdicts=True)
        r = min(res.values(), key=lambda r: r["ms"])
        return r["ms"], r["mode"], r["verdicts"]


def native_side(calls, binary, folder):
    """A :class:`Native` over the batches, or None (with a note) where the tool cannot be built."""
    try:
        return Native(calls, native_occluded.build(binary), folder)
    except MissingPeer as e:
        print(f"note: {e}")
        return None


def median_s(fn, runs, warmup):
    """The median seconds of ``runs`` calls of fn after ``warmup`` untimed ones."""
    return timings(fn, runs, warmup)[0] / 1e3


def brute_verdicts(calls, pick):
    """(clear, blocked) of the float64 brute force on the segments ``pick`` (sorted indices into
    every batch's segments, joined): clear where its verdict is clear of rounding (no crossing,
    or the nearest crossing well within (0, 1) and well inside its triangle)."""
    sizes = np.array([len(c[1]) for c in calls])
    starts = np.concatenate([[0], np.cumsum(sizes)])
    clear, hit = np.zeros(len(pick), bool), np.zeros(len(pick), bool)
    for k, (g, o, d, *_rest) in enumerate(calls):
        m = (pick >= starts[k]) & (pick < starts[k + 1])
        if not m.any():
            continue
        sel = pick[m] - starts[k]
        tris = np.asarray(g.tris, np.float64)
        oo, dd = o[sel], d[sel]
        t, f, _ = brute_cast(tris, oo, dd, 0.0, 1.0)
        h = f >= 0
        clear[m] = ~h | ((t > CLEAR) & (t < 1.0 - CLEAR) & (_bary_min(tris, oo, dd, np.where(h, f, -1)) > CLEAR))
        hit[m] = h
    return clear, hit


def brute_check(calls, blocked, n, rng):
    """(checked, differing) of n segments drawn at random against the float64 brute force, where
    its verdict is clear of rounding."""
    total = sum(len(c[1]) for c in calls)
    pick = np.sort(rng.choice(total, size=min(n, total), replace=False))
    clear, hit = brute_verdicts(calls, pick)
    return int(clear.sum()), int((clear & (blocked[pick] != hit)).sum())


def who_is_right(calls, blocked, theirs, limit, rng):
    """(gridrt right, the other right, unclear) over at most ``limit`` segments (drawn at random) on
    which the flags ``blocked`` and ``theirs`` differ, by the float64 brute force."""
    differ = np.flatnonzero(blocked != theirs)
    pick = np.sort(rng.choice(differ, size=min(limit, len(differ)), replace=False))
    clear, hit = brute_verdicts(calls, pick)
    mine = blocked[pick] == hit
    return int((clear & mine).sum()), int((clear & ~mine).sum()), int((~clear).sum())


def main(argv=None):
    a = parse_args(argv)
    with parallel_first():  # (the renders compile their parallel kernels in this thread, not beside the timing)
        rows = measure(a)
    print("\n".join(md_table(HEADER, rows)))
    return 0


def measure(a):
    """The table's rows."""
    threads = [int(t) for t in items(a.threads)]
    rows = []
    for name in items(a.scenes):
        label, ntri, lights, calls = segments(name, a.size)
        TWINS.wait()
        n = sum(len(c[1]) for c in calls)
        try:
            emb = Occluded(calls)
        except MissingPeer as e:
            print(f"note: embreex not measured: {e}")
            emb = None
        folder = tempfile.TemporaryDirectory(prefix="shadow-native-")
        nat = native_side(calls, a.native_bin, folder.name)
        use_threads(2)
        outs = outputs(calls)
        cast_all(calls, outs, 0.0)
        single = blocked_of(outs)
        for T in threads:
            with Affinity(T), concurrent.futures.ThreadPoolExecutor(T) as pool:
                use_threads(T)
                s = median_s(lambda: cast_all(calls, outs), a.runs, a.warmup)
                blocked = blocked_of(outs)
                if emb:
                    es = median_s(lambda: emb.cast(pool, T), a.runs, a.warmup)
                    eb = emb.blocked(emb.cast(pool, T))
                if nat:
                    nms, nmode, nb = nat.best(T, a.runs, a.warmup, robust=False)
                    rms, rmode, rb = nat.best(T, a.runs, a.warmup, robust=True)
            use_threads(2)
            checked, differ = brute_check(calls, blocked, a.check, np.random.default_rng(1))
            mrays = lambda sec: f"{n / sec / 1e6:.1f}"
            native = ["-"] * 4
            if nat:
                fastest = min(nms, rms) / 1e3
                native = [f"{mrays(nms / 1e3)} ({nmode})", f"{mrays(rms / 1e3)} ({rmode})", f"{fastest / s:.2f}",
                          f"{int((nb != blocked).sum())}, {int((rb != blocked).sum())}"]
                right = who_is_right(calls, blocked, rb, NATIVE_CHECK, np.random.default_rng(2))
                print(f"# {label} T={T}: native robust disagreements checked: gridrt right {right[0]}, native "
                      f"right {right[1]}, unclear {right[2]}", flush=True)
            rows.append([label, f"{ntri:,}", str(lights), f"{n:,}", str(T), mrays(s),
                         "-" if emb is None else mrays(es), native[0], native[1],
                         "-" if emb is None else f"{es / s:.2f}", native[2],
                         str(int((blocked != single).sum())), str(checked), str(differ), native[3]])
            print(f"# {label} T={T}: {mrays(s)} Mrays/s"
                  + ("" if emb is None else f", embreex {mrays(es)}; differ from embreex "
                     f"{int((eb != blocked).sum())}")
                  + ("" if nat is None else f", native {native[0]}, robust {native[1]}"), flush=True)
        folder.cleanup()
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
