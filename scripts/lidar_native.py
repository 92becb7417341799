"""A LiDAR sweep of a deforming mesh every step, against native Embree's refit and cast of the same
rays: BENCHMARKS.md section 19, table "mesh | triangles | rays | threads | gridrt update |
gridrt cast | gridrt step | gridrt step, Lidar.scan | native refit | native cast | native step |
native / gridrt | hits agree" (ms a step).

    bash ../shared/tools/embree-native/build.sh      # the harness (installs libembree-dev)
    .venv/bin/python scripts/lidar_native.py

The mesh: a unit icosphere of about --triangles triangles, deformed every step by the harness's
wave (``y' = y + A sin(2 pi (x / L + t))``, A 5 % of the box diagonal, L half its x extent, t =
0.05 (f + 1)); --frames timed steps after 2 untimed ones, the vertex sets made beforehand for both
sides.  The sensor: ``gridrt.Lidar`` with --channels beams over (-24.9, 2.0) degrees and --columns
azimuths a turn, standing inside the mesh at (0.2, -0.1, 0.05), so every beam returns; its rays,
rounded to float32, are what both sides cast.

Native (the harness ``embree_bench dynamic DIR T FRAMES refit MODE``): per step the next vertex set
is copied into Embree's buffer and committed as a refit, then the rays are cast in 8x8 groups
(8 channels x 8 columns, so a 16-ray packet is 4 x 4 neighbouring beams); the faster of its
16-ray packets and ray streams is kept.  Its ray set must be a square image of a side divisible
by 8, so the sweep's 8x8 groups are laid out as tiles of such an image and the tiles left over
repeat the first ones; its cast time is scaled down by the fraction of repeated tiles.

gridrt: per step ``RayCaster.update`` (the grid rebuilt from scratch) and ``RayCaster.cast`` of
the same float32 rays with t in (0, --max-range) (CGT packets take each column's beams); "step,
Lidar.scan" is the user's call instead of the cast (rays made in numpy from the pose, then cast).
Both sides run pinned to the first T CPUs; every cell is a median over the timed steps.  "hits
agree": the fraction of rays whose triangle is the one native ``rtcIntersect1`` finds on the mesh
at rest (untimed).
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import gridrt
from gridrt.app.bench.affinity import Affinity
from gridrt.app.bench.native import DEFAULT_BIN, check_binary, run_harness
from gridrt.app.bench.output import md_table
from gridrt.config import GridParams
from gridrt.scene import icosphere_mesh
from tables import add_out_option, scene_label, start

DEFAULTS = dict(triangles=1_000_000, channels=64, columns=2048, frames=8, threads="1,2", max_range=120.0)
HEADER = ["mesh", "triangles", "rays", "threads", "gridrt update", "gridrt cast", "gridrt step",
          "gridrt step, Lidar.scan", "native refit", "native cast", "native step", "native / gridrt", "hits agree"]
#: where the sensor stands (inside the unit sphere, off its centre)
SENSOR = (0.2, -0.1, 0.05)
WARMUP = 2


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--triangles", type=int, default=DEFAULTS["triangles"],
                   help="icosphere triangles (the nearest 20 * 4^k; default: the table's, 1000000)")
    p.add_argument("--channels", type=int, default=DEFAULTS["channels"], help="beams a column (default: the table's, 64)")
    p.add_argument("--columns", type=int, default=DEFAULTS["columns"], help="azimuths a turn (default: the table's, 2048)")
    p.add_argument("--frames", type=int, default=DEFAULTS["frames"], help="timed steps (default: the table's, 8)")
    p.add_argument("--threads", default=DEFAULTS["threads"], help="thread counts, comma-separated (default: the table's, 1,2)")
    p.add_argument("--max-range", type=float, default=DEFAULTS["max_range"], help="range limit (default: the table's, 120)")
    p.add_argument("--binary", default=str(DEFAULT_BIN), help="the harness's embree_bench (default: %(default)s)")
    add_out_option(p)
    return start(p, argv)


def wave_frames(V, n):
    """The harness's wave: n vertex sets (n, V, 3) float32 at t = 0.05 (f + 1)."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    A, L = 0.05 * float(np.linalg.norm(hi - lo)), 0.5 * float(hi[0] - lo[0])
    out = np.repeat(V[None].astype(np.float32), n, axis=0)
    for f in range(n):
        out[f, :, 1] = V[:, 1] + A * np.sin(2 * np.pi * (V[:, 0] / L + 0.05 * (f + 1)))
    return out


def tile_layout(channels, columns):
    """(image side RES, index (RES * RES,) of the sweep's ray at each pixel, fraction of tiles that
    repeat others): the sweep's 8 x 8 groups (8 channels x 8 columns) as the image's 8 x 8 tiles in
    the harness's order (row of tiles by row of tiles), the tiles beyond the sweep repeating the
    first ones.  Ray (column a, channel c) is index a * channels + c, Lidar.rays' order."""
    if channels % 8 or columns % 8:
        raise SystemExit("channels and columns must be multiples of 8 (the harness's 8 x 8 groups)")
    groups = (channels // 8) * (columns // 8)
    side = int(np.ceil(np.sqrt(groups)))          # tiles a side
    res = 8 * side
    index = np.empty((res, res), np.int64)
    y, x = np.mgrid[0:8, 0:8]
    for k in range(side * side):
        g = k % groups
        cb, ab = divmod(g, columns // 8)           # channel block, column block
        ty, tx = divmod(k, side)
        index[ty * 8:(ty + 1) * 8, tx * 8:(tx + 1) * 8] = (ab * 8 + x) * channels + cb * 8 + y
    return res, index.reshape(-1), 1.0 - groups / (side * side)


def write_folder(folder, V, F, frames, O, D, index):
    """The harness's folder: the mesh, its vertex sets, the sweep laid out as a square image
    (primary) and in its own order (incoherent, for the hit check)."""
    folder.mkdir(parents=True, exist_ok=True)
    save = lambda name, x: np.save(folder / name, np.ascontiguousarray(x))
    save("vertices.npy", V.astype(np.float32))
    save("faces.npy", F.astype(np.int32))
    save("frames.npy", frames)
    save("primary_origins.npy", O[index])
    save("primary_directions.npy", D[index])
    save("incoherent_origins.npy", O)
    save("incoherent_directions.npy", D)


def median_ms(ts):
    return 1e3 * float(np.median(ts))


def gridrt_steps(V, F, frames, O, D, lidar, pose, T, max_range):
    """(update, cast, step, step with Lidar.scan) median ms over the timed steps, and the rest mesh's
    triangle per ray."""
    caster = gridrt.RayCaster(V, F, GridParams(threads=T))
    rest = caster.cast(O, D, t_max=max_range, threads=T).tri
    up, cast, scan = [], [], []
    for f, v in enumerate(frames):
        t0 = time.perf_counter()
        caster.update(v)
        t1 = time.perf_counter()
        caster.cast(O, D, t_max=max_range, threads=T)
        t2 = time.perf_counter()
        lidar.scan(caster, pose, threads=T)
        t3 = time.perf_counter()
        if f >= WARMUP:
            up.append(t1 - t0)
            cast.append(t2 - t1)
            scan.append(t3 - t2)
    return median_ms(up), median_ms(cast), median_ms(np.add(up, cast)), median_ms(np.add(up, scan)), rest


def native_steps(binary, folder, T, timed, repeated):
    """(refit ms, cast ms, step ms) of the faster mode (16-ray packets or streams), the cast scaled
    to the sweep's own rays."""
    best = None
    for mode in ("p16", "1M"):
        r = run_harness(binary, ["dynamic", folder, T, timed, "refit", mode])[0]
        cast = 1e3 * r["cast_s"] * (1.0 - repeated)
        update = 1e3 * r["update_s"]
        if best is None or update + cast < best[2]:
            best = (update, cast, update + cast)
    return best


def main(argv=None):
    a = parse_args(argv)
    binary = check_binary(a.binary)
    m = icosphere_mesh(a.triangles)
    V, F = m.vertices.astype(np.float32), m.faces.astype(np.int32)
    frames = wave_frames(V, WARMUP + a.frames)
    lidar = gridrt.Lidar(channels=a.channels, vertical_fov=(-24.9, 2.0), azimuth_resolution=360.0 / a.columns,
                         max_range=a.max_range)
    pose = np.eye(4)
    pose[:3, 3] = SENSOR
    o, d, _ = lidar.rays(pose)
    O, D = o.astype(np.float32), d.astype(np.float32)
    res, index, repeated = tile_layout(lidar.channels, lidar.columns)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "lidar"
        write_folder(folder, V, F, frames, O, D, index)
        hdir = Path(tmp) / "hits"
        hdir.mkdir()
        run_harness(binary, ["static", folder, 1, 1, "--modes", "1", "--builds", "low", "--hits", hdir])
        native_tri = np.load(hdir / "incoherent_1_tri.npy")
        for T in (int(x) for x in a.threads.split(",")):
            with Affinity(T):
                n_up, n_cast, n_step = native_steps(binary, folder, T, a.frames, repeated)
                g_up, g_cast, g_step, g_scan, rest = gridrt_steps(V, F, frames, O.astype(np.float64),
                                                                  D.astype(np.float64), lidar, pose, T, a.max_range)
            rows.append([scene_label("icosphere", len(F)), f"{len(F):,}", f"{len(O):,}", str(T), f"{g_up:.1f}",
                         f"{g_cast:.1f}", f"{g_step:.1f}", f"{g_scan:.1f}", f"{n_up:.1f}", f"{n_cast:.1f}",
                         f"{n_step:.1f}", f"{n_step / g_step:.2f}", f"{np.mean(rest == native_tri):.4f}"])
            print(f"# {T} thread(s) done", flush=True)
    print(f"image {res}x{res} for the harness: {100 * repeated:.1f} % of its tiles repeat others (its cast scaled)")
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
