"""BENCHMARKS.md section 8, table "offset X | hit/miss flips | median rel. t error": the Utah
teapot moved far from the world origin and rendered through the command line.

    .venv/bin/python scripts/far_origin.py

For each offset X the teapot is written to an OBJ file with X * (1, -0.7, 0.3) added to its
vertices (17 significant digits), and one frame of it is rendered with ``gridrt dump
--save-buffers`` (serial build, CGT, 160x120) by a camera moved alike.  Each pixel's hit and t are
compared with a float64 brute force over the teapot at offset 0
(gridrt.app.bench.reference.brute_cast) on the same pixels' rays: hit/miss flips, and the median
relative error of t over the pixels both hit.  Nothing here is timed.
"""

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from gridrt.app.bench.output import md_table
from gridrt.app.bench.reference import brute_cast, pixel_rays
from gridrt.app.bench.scenes import data_path
from gridrt.frame import ViewSpec
from gridrt.scene import load_mesh

from tables import add_out_option, items, start

OFFSETS = "0,1e3,1e5,1e6,1e7,1e9"
#: the direction of the offset: not along an axis, so every coordinate is large
AXIS = np.array([1.0, -0.7, 0.3])
#: the direction the camera looks at the teapot from
VIEW_DIR = np.array([0.55, 0.45, 1.0])
HEADER = ["offset X", "hit/miss flips", "median rel. t error"]


def view_of(lo, hi, dist=1.3):
    c = 0.5 * (lo + hi)
    return c + VIEW_DIR / np.linalg.norm(VIEW_DIR) * dist * float(np.linalg.norm(hi - lo)), c


def write_obj(path, v, f):
    with open(path, "w") as fh:
        fh.writelines("v %.17g %.17g %.17g\n" % tuple(p) for p in v)
        fh.writelines("f %d %d %d\n" % tuple(q) for q in f + 1)


def vec(v):
    return ",".join(repr(float(x)) for x in v)


def dump_hits(folder, obj, eye, target, W, H):
    """(t, tri) of one frame of ``gridrt dump --save-buffers`` of obj seen from eye towards target."""
    cmd = [sys.executable, "-m", "gridrt", "dump", "--scene", str(obj), "--frames", "1", "--size", f"{W}x{H}",
           "--strategy", "serial", "--threads", "1", "--traversal", "cgt", "--save-buffers",
           f"--eye={vec(eye)}", f"--target={vec(target)}", "--out", str(folder), "--no-progress"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    if r.returncode != 0:
        raise SystemExit(f"gridrt dump failed on {obj}:\n{r.stderr[-2000:]}")
    return (np.load(folder / "frame_00000_t.npy").reshape(-1).astype(np.float64),
            np.load(folder / "frame_00000_id.npy").reshape(-1))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--offsets", default=OFFSETS, help="comma-separated offsets X (default: the table's, %(default)s)")
    p.add_argument("--size", default="160x120", help="image WxH (default: the table's, %(default)s)")
    add_out_option(p)
    a = start(p, argv)
    W, H = (int(x) for x in a.size.lower().split("x"))
    path = data_path("teapot")
    m = load_mesh(str(path))
    v, f = m.vertices64, m.faces.astype(np.int64)
    print(f"scene: {path}, {len(f):,} triangles, {float((v.max(axis=0) - v.min(axis=0)).max()):.1f} units across")
    print()
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    ys, xs = np.divmod(np.arange(W * H), W)
    o, d = pixel_rays(eye, target, ViewSpec().up, ViewSpec().fov, W, H, xs, ys)
    ref_t, ref_tri, _ = brute_cast(v[f], o, d)
    ref_hit = ref_tri >= 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for text in items(a.offsets):
            X = float(text)
            off = X * AXIS
            obj = Path(tmp) / f"teapot_{text}.obj"
            write_obj(obj, v + off, f)
            t, tri = dump_hits(Path(tmp) / f"out_{text}", obj, eye + off, target + off, W, H)
            hit = tri >= 0
            both = hit & ref_hit
            rel = float(np.median(np.abs(t[both] - ref_t[both]) / ref_t[both]))
            rows.append([text, str(int((hit != ref_hit).sum())), f"{rel:.1e}"])
            print(f"offset {text}: {rows[-1][1]} flips, median relative t error {rows[-1][2]}", flush=True)
    print()
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
