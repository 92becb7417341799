"""Shadow segments left out by light maps: BENCHMARKS.md section 15, table "scene | lights | threads
| frame ms without maps | frame ms with maps | with / without | shadow rays/px | shown clear | shown
blocked | shadow Mrays/s without maps | shadow Mrays/s with maps | maps made (ms, once) | map memory |
frames identical".

    .venv/bin/python scripts/light_maps.py

Each scene is rendered through its own camera at SIZE x 3/4 SIZE (SIZE 1024), ``material`` shading
with hard shadows of every light (the CGT traversal, the frame pipeline: the scene's static part in
a grid of its own, kept from frame to frame), by two pipelines in turns: one whose renderer makes
light maps for its point lights over the static grid (gridrt.trace.lightmap, the default) and one
whose renderer makes none.  Frames step from ``--t`` by 1/30 s (the camera and the moving parts
move, the lights and the static part stay); frame ms: the median of ``--runs`` frames after
untimed ones, one and then one for each light (the maps are made one a frame from the second), at
each thread count (the process pinned to as many cores).  Shown clear: the share of the shadow
segments that the maps showed clear, which the static grid then does not cast; shown blocked:
those they showed blocked, which no grid casts.  Shadow Mrays/s: a frame's shadow segments over the
median time of its batch casts (gridrt.trace.batch.cast_grouped), with maps the maps' test
(gridrt.trace.lightmap.clear_lit) counted in: the segments whose verdict is found, a second.  Maps made: the
time of making them and of putting the triangles in clusters (once, with the first map); map
memory: the maps' and the clusters' arrays.  Every timed frame of the two pipelines is compared
pixel for pixel, in the image and the colours before clamping.
"""

import argparse
import importlib
import time

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.stats import stat
from gridrt.trace.lightmap import K, RES, NoLightMaps
from gridrt.trace.twin import TWINS
from tables import (add_out_option, add_own_camera_options, material_pipeline, own_camera_runs, print_table,
                    start)

#: the module whose build_light_map LightMaps calls (timed through it)
LIGHTMAP = importlib.import_module("gridrt.trace.lightmap")
SCENES = "kitchen:5,museum:0"
HEADER = ["scene", "lights", "threads", "frame ms without maps", "frame ms with maps", "with / without",
          "shadow rays/px", "shown clear", "shown blocked", "shadow Mrays/s without maps", "shadow Mrays/s with maps",
          "maps made (ms, once)", "map memory", "frames identical"]
#: the module whose cast_grouped and clear_lit the material pass calls (timed through it)
RENDER = importlib.import_module("gridrt.trace.render")


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_own_camera_options(p, SCENES)
    p.add_argument("--threads", default="1,2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=15, help="timed frames, the median kept (default: the table's, 15)")
    add_out_option(p)
    return start(p, argv)


class Timed:
    """While entered, the functions ``names`` of ``module`` are timed where they are called
    through it: s[name] their seconds, n[name] their calls; seconds() the sum."""

    def __init__(self, module, *names):
        self.module, self.fns = module, {name: getattr(module, name) for name in names}
        self.s, self.n = dict.fromkeys(names, 0.0), dict.fromkeys(names, 0)

    def _timed(self, name, fn):
        def timed(*args, **kw):
            t0 = time.perf_counter()
            out = fn(*args, **kw)
            self.s[name] += time.perf_counter() - t0
            self.n[name] += 1
            return out
        return timed

    def __enter__(self):
        for name, fn in self.fns.items():
            setattr(self.module, name, self._timed(name, fn))
        return self

    def __exit__(self, *exc):
        for name, fn in self.fns.items():
            setattr(self.module, name, fn)

    def seconds(self):
        return sum(self.s.values())


def pipeline(sc, size, threads, maps):
    """The frame pipeline of one side: the scene through its own camera, material and shadows."""
    pipe = material_pipeline(sc, size, threads)
    if not maps:
        pipe.renderer._lightmaps = NoLightMaps()
    return pipe


def measure(a):
    rows = []
    for sc, t0, T in own_camera_runs(a):
        on, off = pipeline(sc, a.size, T, True), pipeline(sc, a.size, T, False)
        with Timed(LIGHTMAP, "build_light_map", "plane_clusters") as built:   # (the maps, the clusters)
            lights, k = 1, 0
            while k < 1 + lights:   # (compiles, the static grid; then a light's map a frame)
                lights = int(on.step(t0 + k / 30).stats["lights"])
                off.step(t0 + k / 30)
                k += 1
        TWINS.wait()
        times, shadow = {True: [], False: []}, {True: [], False: []}
        same, segs, left, shut = 0, 0, 0, 0
        for k in range(k, k + a.runs):
            t = t0 + k / 30
            f = {}
            for side, p in ((True, on), (False, off)):   # in turns
                s = time.perf_counter()
                with Timed(RENDER, "cast_grouped", "clear_lit") as casts:
                    fr = p.step(t)
                times[side].append((time.perf_counter() - s) * 1e3)
                shadow[side].append(casts.seconds())
                f[side] = (fr.image.copy(), fr.hdr.copy(), fr.stats)
            same += np.array_equal(f[True][0], f[False][0]) and np.array_equal(f[True][1], f[False][1])
            segs += f[True][2]["shadow_rays_per_pixel"] * a.size * (a.size * 3 // 4)
            left += on.renderer.shadow_clear
            shut += on.renderer.shadow_blocked
        ms = {side: stat(v)[0] for side, v in times.items()}
        st = f[True][2]
        rate = {side: segs / a.runs / max(stat(v)[0], 1e-9) / 1e6 for side, v in shadow.items()}
        cl = on.renderer._lightmaps._clusters
        made = built.n["build_light_map"]
        mib = (made * 6 * RES * RES * (K * 8 + 4) + sum(x.nbytes for x in (cl.of, cl.planes, cl.lone))) / 2**20
        rows.append([sc.label, str(int(st["lights"])), str(T), f"{ms[False]:.1f}", f"{ms[True]:.1f}",
                     f"{ms[True] / ms[False]:.2f}", f"{st['shadow_rays_per_pixel']:.2f}",
                     f"{left / max(segs, 1):.1%}", f"{shut / max(segs, 1):.1%}", f"{rate[False]:.1f}",
                     f"{rate[True]:.1f}", f"{made} lights, {1e3 * built.seconds():.0f}",
                     f"{mib:.1f} MiB", f"{same} of {a.runs}"])
        print(f"# {sc.label} T={T}: {ms[False]:.1f} -> {ms[True]:.1f} ms, shown clear {left / max(segs, 1):.1%}, "
              f"blocked {shut / max(segs, 1):.1%}",
              flush=True)
    return rows


def main(argv=None):
    return print_table(HEADER, measure, parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
