"""BENCHMARKS.md section 12, "512-bit vectors on whole frames": ``gridrt bench frame`` with
``GRIDRT_VECTOR_WIDTH=256`` and then with the default (512-bit code on CPUs with AVX-512F),
back to back, for several rounds; build and render ms at each thread count.

    .venv/bin/python scripts/vector_width.py

makes the table (1024x1024, 5 timed frames after 2 warm-up in each run, 2 rounds, the median of
the rounds' medians); ``--scenes icosphere:1280:twist --size 64 --runs 1 --rounds 1`` is a quick
check.  The vector width is fixed when numba starts, so each run is its own ``gridrt bench frame``
process (float64 packets, split on, the strategy bench frame picks).  On a CPU without AVX-512F
both columns run the same 256-bit code; the script says so.
"""

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from gridrt.app.bench.output import md_table

from tables import add_frame_options, build_render_rows, items, start

SCENES = "icosphere:20480:twist,lucy:twist,icosphere:1310720:twist"
WIDTHS = (("256-bit", "256"), ("512-bit", "auto"))
HEADER = ["scene", "build, 256-bit", "build, 512-bit", "render, 256-bit", "render, 512-bit"]


def has_avx512():
    """True when the CPU reports AVX-512F (Linux /proc/cpuinfo; False elsewhere)."""
    try:
        return " avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


def run_frame(width, a, out):
    """Rows of frame.csv of one ``gridrt bench frame`` run with GRIDRT_VECTOR_WIDTH=width."""
    cmd = [sys.executable, "-m", "gridrt", "bench", "frame", "--scenes", a.scenes, "--threads", a.threads,
           "--split", "on", "--size", str(a.size), "--runs", str(a.runs), "--warmup", str(a.warmup),
           "--no-progress", "--out", str(out)]
    env = dict(os.environ, GRIDRT_VECTOR_WIDTH=width)
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"gridrt bench frame with GRIDRT_VECTOR_WIDTH={width} failed:\n{r.stderr[-2000:]}")
    with open(out / "frame.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_frame_options(p, SCENES)
    a = start(p, argv)
    if not has_avx512():
        print("this CPU has no AVX-512F: both columns run 256-bit code")
    print("build ms / render ms medians at threads " + " / ".join(items(a.threads)) +
          f", the median over {a.rounds} rounds of each run's median")
    print()
    got = {}  # (scene, width label, threads) -> [(build, render)]
    tris = {}  # scene -> triangles
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(a.rounds):
            for label, width in WIDTHS:
                for row in run_frame(width, a, Path(tmp) / f"{width}-{rnd}"):
                    key = (row["scene"], label, int(row["threads"]))
                    got.setdefault(key, []).append((float(row["build_ms"]), float(row["render_ms"])))
                    tris[row["scene"]] = int(row["triangles"])
    threads = [int(t) for t in items(a.threads)]
    rows = build_render_rows(items(a.scenes), [label for label, _ in WIDTHS], got, tris, threads)
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
