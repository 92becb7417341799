"""``gridrt bench cluster``: a frame dump in one process against the same dump on local Dask
clusters.

Each configuration is the real command, ``gridrt dump`` in a subprocess, with the same scene,
frames and size: one process with T threads, a local cluster of N workers x 1 thread, and one of
1 worker x T threads (T, N: the cores; ``--configs`` chooses others).  The figures come from
outside the command: its wall time from start to exit, and the write times (mtime) of its first
and last PNG, so that a process's start (Python, the scene's load, the kernels' warm-up, a
cluster's start) is kept apart from its steady rate: the frames written in the middle half of the
run over its duration (a cluster's client writes a chunk of frames at once: a rate from the
first write would count the first chunks as free).
The cluster's own start (the dump prints it) and the bytes the client received are reported too.
Configurations are run in turns, ``runs`` times; medians [min-max].
"""

import io
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gridrt.errors import InputError
from gridrt.scene import make_scene

from ..bench.machine import finish_machine, machine_info
from ..bench.options import check_runs
from ..bench.output import md_table, out_dir, progress, write_csv, write_json, write_summary
from ..bench.scenes import scene_available, scene_spec
from ..frame_out import write_file
from .scheduler import check_workers, import_distributed

CLUSTER_SCENE = "kitchen"
CLUSTER_FALLBACK = "marbles"


def add_parser(bsub, common):
    p = bsub.add_parser("cluster", help="frames/s of a dump in one process against local Dask clusters",
                        description=__doc__.split("\n\n")[0])
    common(p, "cluster", runs=1, warmup=0)
    p.add_argument("--scene", default=None,
                   help=f"scene (default {CLUSTER_SCENE}, or {CLUSTER_FALLBACK} where the data set is absent)")
    p.add_argument("--frames", type=int, default=120, help="frames per dump (default 120)")
    p.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    p.add_argument("--configs", default=None,
                   help="configurations, comma-separated: 1pT (one process, T threads) or NxT (a local cluster of N "
                        "workers x T threads); default 1pC,Cx1,1xC with C the cores")
    p.add_argument("--dump-args", default="--follow-camera",
                   help="further options of every dump (default %(default)s: the scene's own camera where it has one)")
    p.set_defaults(func=run_cluster_bench)


def parse_configs(text, cores):
    """[(label, workers or None, threads)] from '1p2,2x1,1x2'."""
    out = []
    for item in (text or f"1p{cores},{cores}x1,1x{cores}").split(","):
        m = re.fullmatch(r"\s*(\d+)\s*([px])\s*(\d+)\s*", item)
        if not m or int(m.group(1)) < 1 or int(m.group(3)) < 1 or (m.group(2) == "p" and m.group(1) != "1"):
            raise InputError(f"--configs: expected 1pT (one process, T threads) or NxT (N workers x T threads), "
                             f"got {item!r}")
        n, kind, t = int(m.group(1)), m.group(2), int(m.group(3))
        label = f"1 process x {t} threads" if kind == "p" else f"cluster {n} worker{'s' * (n > 1)} x {t} thread{'s' * (t > 1)}"
        out.append((label, None if kind == "p" else n, t))
    return out


def _one(args, out, cfg):
    """Run one dump; its figures."""
    label, workers, threads = cfg
    cmd = [sys.executable, "-m", "gridrt", "dump", *args, "--threads", str(threads), "--out", str(out), "--no-progress"]
    if workers is not None:
        cmd += ["--workers", str(workers)]
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t0
    if r.returncode != 0:
        raise InputError(f"{label}: the dump failed: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    pngs = sorted(Path(out).glob("frame_*.png"))
    times = np.sort([p.stat().st_mtime for p in pngs])
    n = len(times)
    a, b = n // 4, (3 * n) // 4
    m = re.search(r"cluster start ([\d.]+) s", r.stdout)
    return {"wall_s": wall, "first_frame_s": times[0] - t0, "steady_fps": (b - a) / max(times[b] - times[a], 1e-9),
            "fps": n / wall, "cluster_start_s": float(m.group(1)) if m else float("nan"),
            "png_mb": sum(p.stat().st_size for p in pngs) / 1e6}


def _costs(source, args, png, runs=5):
    """What the model of a large cluster needs, measured here: the scene's load (s), a PNG's
    encoding and its write by the client (ms), medians of ``runs``."""
    from PIL import Image  # deferred: Pillow loads only when this benchmark decodes and encodes a PNG

    load = []
    for _ in range(runs):
        t0 = time.perf_counter()
        make_scene(source)
        load.append(time.perf_counter() - t0)
    img = np.asarray(Image.open(png).convert("RGB"))
    enc, write = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(runs):
            t0 = time.perf_counter()
            buf = io.BytesIO()
            Image.fromarray(img).save(buf, format="PNG")
            enc.append((time.perf_counter() - t0) * 1e3)
            t0 = time.perf_counter()
            write_file(Path(tmp) / f"frame_{i:05d}.png", buf.getvalue())
            write.append((time.perf_counter() - t0) * 1e3)
    return {"load_s": float(np.median(load)), "png_encode_ms": float(np.median(enc)),
            "client_write_ms": float(np.median(write))}


def run_cluster_bench(a):
    check_runs(a.runs, a.warmup)
    import_distributed()
    cores = os.cpu_count() or 1
    configs = parse_configs(a.configs, cores)
    for workers in sorted({w for _, w, _ in configs if w is not None}):  # (before any run starts)
        check_workers(workers)
    frames, size = (6, 64) if a.quick else (a.frames, a.size)
    if frames < 2:
        raise InputError(f"--frames must be at least 2, got {frames}")
    text = a.scene or (CLUSTER_SCENE if scene_available(CLUSTER_SCENE) else CLUSTER_FALLBACK)
    source = scene_spec(text).source
    args = ["--scene", source, "--frames", str(frames), "--size", f"{size}x{size}", *a.dump_args.split()]
    out = out_dir(a.out)
    info = machine_info(sorted({t for _, _, t in configs}), probe=not a.quick)
    samples = {c[0]: [] for c in configs}
    bar = progress(len(configs) * (a.runs + a.warmup), "bench cluster", a.no_progress)
    with tempfile.TemporaryDirectory(prefix="gridrt-bench-cluster-") as tmp:
        for i in range(a.warmup + a.runs):
            for cfg in configs:  # in turns, so load from other processes falls on all alike
                bar.set_postfix_str(cfg[0])
                fig = _one(args, Path(tmp) / f"{i}-{len(samples[cfg[0]])}-{cfg[1]}-{cfg[2]}", cfg)
                if i >= a.warmup:
                    samples[cfg[0]].append(fig)
                bar.update(1)
        costs = _costs(source, args, next((Path(tmp)).glob("*/frame_00000.png")))
    bar.close()
    info["costs"] = costs
    rows = []
    for label, workers, threads in configs:
        smp = samples[label]
        row = dict(config=label, workers=workers or 0, threads=threads, scene=text, frames=frames, size=size,
                   runs=len(smp))
        for k in ("wall_s", "first_frame_s", "fps", "steady_fps", "cluster_start_s", "png_mb"):
            v = np.array([s[k] for s in smp], np.float64)
            row[k], row[k + "_min"], row[k + "_max"] = float(np.median(v)), float(v.min()), float(v.max())
        rows.append(row)
    finish_machine(info)
    write_csv(rows, out / "cluster.csv")
    write_json(info, out / "machine.json")
    base = rows[0]["steady_fps"]

    def cell(r, k, f="{:.2f}"):
        return f"{f.format(r[k])} [{f.format(r[k + '_min'])}-{f.format(r[k + '_max'])}]"

    body = [f"`gridrt dump {' '.join(args)}` per configuration, {a.runs} run(s) each after {a.warmup} warm-up, "
            f"in turns; medians [min-max].  Steady frames/s: the frames written in the middle half of the run over its "
            f"duration (PNG write times); "
            f"first frame: from the command's start to its first PNG (Python, the scene's load, the kernels' "
            f"warm-up, a cluster's start).", "",
            *md_table(["configuration", "frames/s (steady)", f"vs {rows[0]['config']}", "frames/s (whole command)",
                       "first frame s", "cluster start s", "wall s"],
                      [[r["config"], cell(r, "steady_fps"), f"{r['steady_fps'] / base:.2f}x", cell(r, "fps"),
                        cell(r, "first_frame_s"), "-" if r["workers"] == 0 else cell(r, "cluster_start_s"),
                        cell(r, "wall_s", "{:.1f}")] for r in rows]),
            "", f"PNG output: {rows[0]['png_mb']:.1f} MB for {frames} frames ({rows[0]['png_mb'] / frames:.2f} MB a frame).  "
            f"Measured in this process: the scene loads in {costs['load_s']:.2f} s, a frame's PNG encodes in "
            f"{costs['png_encode_ms']:.1f} ms (on a worker, in its frame time) and the client writes it in "
            f"{costs['client_write_ms']:.2f} ms."]
    write_summary(out / "summary.md", "gridrt bench cluster", info, [("Results", body)])
    for line in body:
        if line.startswith("|"):
            print(line)
    print(f"wrote {out}/cluster.csv, summary.md")
    return 0
