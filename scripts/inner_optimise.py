"""BENCHMARKS.md section 10, "An inner kernel's module is optimised only within its callers":
``gridrt bench frame`` as gridrt compiles (an inner kernel's LLVM module optimised only in the
libraries of the kernels that call it) and as numba compiles (each inner kernel's module
optimised on its own first, and again in each caller), back to back, for several rounds; build
and render ms at each thread count.

    .venv/bin/python scripts/inner_optimise.py

makes the table (1024x1024, 5 timed frames after 2 warm-up in each run, 2 rounds, the median of
the rounds' medians); ``--scenes icosphere:1280:twist --size 64 --runs 1 --rounds 1`` is a quick
check.  Each run is its own process with an empty numba cache of its own (the two ways store
different code under the same cache keys), so each also times its cold compile: the run's wall
time, in the last column (bench frame's compiles of its build strategies and render kernels, at
every thread count).  numba's way is gridrt with the method that skips the optimisation removed
(``del gridrt.compiles._InnerLibrary._optimize_final_module``) before the benchmark starts.
"""

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gridrt.app.bench.output import md_table

from tables import add_frame_options, build_render_rows, items, start

SCENES = "marbles,icosphere:20480:twist,lucy:twist"
RUN = ("import sys\n"
       "import gridrt.compiles\n"
       "if sys.argv[1] == 'numba':\n"
       "    del gridrt.compiles._InnerLibrary._optimize_final_module\n"
       "from gridrt.app.__main__ import main\n"
       "sys.exit(main(sys.argv[2:]))\n")
WAYS = (("gridrt", "gridrt"), ("numba", "numba"))
HEADER = ["scene", "build, gridrt", "build, numba", "render, gridrt", "render, numba"]


def run_frame(way, a, out):
    """(rows of frame.csv, wall s) of one ``gridrt bench frame`` run compiled the way ``way``."""
    cmd = [sys.executable, "-c", RUN, way, "bench", "frame", "--scenes", a.scenes, "--threads", a.threads,
           "--size", str(a.size), "--runs", str(a.runs), "--warmup", str(a.warmup), "--no-progress", "--out",
           str(out)]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(out / "numba-cache"))
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"gridrt bench frame compiled {way}'s way failed:\n{r.stderr[-2000:]}")
    with open(out / "frame.csv", newline="") as fh:
        return list(csv.DictReader(fh)), wall


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_frame_options(p, SCENES)
    a = start(p, argv)
    print("build ms / render ms medians at threads " + " / ".join(items(a.threads)) +
          f", the median over {a.rounds} rounds of each run's median")
    print()
    got = {}  # (scene, way, threads) -> [(build, render)]
    walls = {way: [] for way, _ in WAYS}
    tris = {}  # scene -> triangles
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(a.rounds):
            for label, way in WAYS:
                rows, wall = run_frame(way, a, Path(tmp) / f"{way}-{rnd}")
                walls[label].append(wall)
                for row in rows:
                    key = (row["scene"], label, int(row["threads"]))
                    got.setdefault(key, []).append((float(row["build_ms"]), float(row["render_ms"])))
                    tris[row["scene"]] = int(row["triangles"])
    threads = [int(t) for t in items(a.threads)]
    rows = build_render_rows(items(a.scenes), [label for label, _ in WAYS], got, tris, threads)
    print("\n".join(md_table(HEADER, rows)))
    print()
    print("whole run (cold compile and every frame), s: " +
          "; ".join(f"{label} {', '.join(f'{w:.1f}' for w in walls[label])}" for label, _ in WAYS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
