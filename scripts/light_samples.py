"""Shadow rays towards lights drawn per pixel, against a ray towards every light: BENCHMARKS.md
section 6, table "scene | lights | shadow rays | threads | frame ms | fps | shadow rays/px | draws
averaged | ms to this image | RMSE (levels) | pixels off by > 2 levels | most off (levels)".

    .venv/bin/python scripts/light_samples.py

Each scene is rendered through its own camera at SIZE x 3/4 SIZE (SIZE 1024) at time ``--t`` (the
kitchen's 5 s; the museum's 0 s), ``material`` shading with hard shadows (the CGT traversal, the
frame pipeline: the scene's split static and moving grids, the moving one rebuilt every frame),
once with a shadow ray towards every light that lights a hit (``RenderParams.light_samples`` 0,
exact) and once for each ``--samples`` k with k rays a pixel towards lights drawn by their light
there (``light_samples`` k).  Frame ms: the median of ``--runs`` frames after ``--warmup``, at each
thread count (the process pinned to as many cores), the modes in turns.

The error of a drawn image is counted against the exact image of the same frame, in 8-bit levels
over the RGB channels of every pixel: the first draw alone (seed 0), then the mean of the draws of
seeds 0 .. N-1 as the viewer shows it while the view is still (``gridrt.app.viewer.accumulate
.Accumulator`` over the frames' images and their colours before clamping) for each ``--draws`` N;
"ms to this image" is N frames.
"""

import argparse
import time

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.stats import stat
from gridrt.app.viewer.accumulate import Accumulator
from gridrt.trace.twin import TWINS
from tables import (add_out_option, add_own_camera_options, items, material_pipeline, own_camera_runs,
                    print_table, start)

SCENES = "kitchen:5,museum:0"
HEADER = ["scene", "lights", "shadow rays", "threads", "frame ms", "fps", "shadow rays/px", "draws averaged",
          "ms to this image", "RMSE (levels)", "pixels off by > 2 levels", "most off (levels)"]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_own_camera_options(p, SCENES)
    p.add_argument("--samples", default="1,2,4", help="light_samples values measured beside the exact render "
                   "(default: the table's, %(default)s)")
    p.add_argument("--draws", default="4,16,64", help="draws averaged, beside the first alone (default: the "
                   "table's, %(default)s)")
    p.add_argument("--threads", default="2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=5, help="timed frames, the median kept (default: the table's, 5)")
    p.add_argument("--warmup", type=int, default=1, help="untimed frames first (default: the table's, 1)")
    add_out_option(p)
    return start(p, argv)


def error(img, exact):
    """(RMSE, fraction of pixels off by more than 2 levels in a channel, most off) in levels."""
    d = img[..., :3].astype(np.float64) - exact[..., :3]
    off = np.abs(d).max(axis=-1)
    return float(np.sqrt((d * d).mean())), float((off > 2).mean()), int(off.max())


def averaged(pipe, t, n, exact):
    """The errors of the mean of draws 0 .. m-1 for each m in n (sorted), as the viewer shows them."""
    acc, out = Accumulator(max_samples=max(n)), {}
    rp = pipe.render_params
    for seed in range(max(n)):
        pipe.render_params = rp.replace(light_seed=seed)
        fr = pipe.step(t)
        shown = acc.add("still", fr.image, fr.hdr)
        if seed + 1 in n:
            out[seed + 1] = error(shown, exact)
    pipe.render_params = rp
    return out


def measure(a):
    rows = []
    ks = [int(k) for k in items(a.samples)]
    n = sorted({1, *(int(d) for d in items(a.draws))})
    for sc, t, T in own_camera_runs(a):
        pipes = {k: material_pipeline(sc, a.size, T, k) for k in [0, *ks]}
        for p in pipes.values():  # (compiles, and the static grid)
            p.step(t)
        TWINS.wait()
        times, last = {k: [] for k in pipes}, {}
        for r in range(a.warmup + a.runs):
            for k, p in pipes.items():  # in turns
                t0 = time.perf_counter()
                last[k] = p.step(t)
                if r >= a.warmup:
                    times[k].append((time.perf_counter() - t0) * 1e3)
        ms = {k: stat(v)[0] for k, v in times.items()}
        exact = last[0].image.copy()   # (each pipeline renders into buffers of its own)
        lights = int(last[0].stats["lights"])
        for k in pipes:
            st = last[k].stats
            rays = f"{st['shadow_rays_per_pixel']:.2f}"
            label = "every light" if k == 0 else f"{k} drawn a pixel"
            errs = {1: (0.0, 0.0, 0)} if k == 0 else averaged(pipes[k], t, n, exact)
            for m, (rmse, off, most) in errs.items():
                rows.append([sc.label, str(lights), label, str(T), f"{ms[k]:.1f}" if m == 1 else "",
                             f"{1e3 / ms[k]:.1f}" if m == 1 else "", rays if m == 1 else "", str(m),
                             f"{m * ms[k]:.0f}", f"{rmse:.2f}", f"{100 * off:.2f}%", str(most)])
            print(f"# {sc.label} T={T} {label}: {ms[k]:.1f} ms, {rays} shadow rays/px; "
                  + ", ".join(f"{m}: RMSE {e[0]:.2f}" for m, e in errs.items()), flush=True)
    return rows


def main(argv=None):
    return print_table(HEADER, measure, parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
