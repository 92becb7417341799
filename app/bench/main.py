"""``gridrt bench SUBCOMMAND``: benchmarks.  Each subcommand writes a CSV, PNG plots, a short
``summary.md`` and ``machine.json`` (CPU model, cores, threads used, versions, commit, load
average, effective cores) into ``--out``, and shows progress bars.  Every timing is the median of ``--runs`` runs
after ``--warmup`` untimed runs (numba compiles, buffers grow), with min and max.

* ``core``:  serial grid build (bbox and exact insertion) and primary-ray Mrays/s (DDA and CGT)
  at 1 thread and all cores on a ~100k and a ~1M triangle mesh.
* ``build``: build strategies x thread counts x scenes, total and per stage (Ize et al.
  2006's "Comparison build methods" and "Individual steps"; :func:`gridrt.app.bench.sweep.run_build_sweep`),
  and a render of each configuration's grid (render ms, tests and cells per ray).
* ``frame``: animation + rebuild + render per frame at 1024x1024 for each scene at 1 thread and
  all cores (Ize et al. 2006's "Total performance", CGT's fps table); CGT traversal by default (DDA on
  request), static/moving split on and off.

``build``, ``frame`` and ``peers`` take ``--grid`` (grid kinds, comma-separated: uniform,two_level
measures both side by side) with ``--top-density`` and ``--leaf-density``; every row records the
grid kind asked for and built, the densities, cells (a two-level grid's leaf cells), references,
grid bytes and bytes per triangle (:func:`gridrt.app.bench.util.grid_columns`).
* ``trade``: every knob that trades speed for accuracy against a brute-force float64 reference
  (:mod:`gridrt.app.bench.trade`).
* ``peers``: the same animated mesh and rays through Intel Embree (embreex) side by side
  (:mod:`gridrt.app.bench.peers`).
* ``start``: cold (fresh numba cache) and warm start of ``gridrt dump --frames 1`` to its first
  frame, wall and CPU time (:mod:`gridrt.app.bench.start`).
* ``cluster``: frames/s of a dump in one process against local Dask clusters
  (:mod:`gridrt.app.bench.cluster_bench`).

``build`` and ``frame`` take ``--workers N`` / ``--scheduler ADDRESS`` to spread their
configurations over a Dask cluster (:mod:`gridrt.app.bench.on_cluster`).
"""

import sys
import time

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.config import INSERT_MODES, SHADING_MODES, TRAVERSALS, GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid.build import GridBuilder
from gridrt.threads import check_threads
from gridrt.trace.render import Renderer

from ..cli import add_packet_args, defaults
from ..cluster import add_cluster_args, wants_cluster
from .util import (
    add_grid_kind_args, check_frame_args, check_runs, facing_camera, figure, finish_machine, fmt_ms, grid_columns,
    grid_kinds, machine_info, md_table, out_dir, progress, put_stat, resolve_scene, scene_list, scenes_help, stat,
    thread_list, write_csv, write_json, write_summary,
)

#: the fps figures of Ize et al. 2006 and of CGT (Wald et al. 2006, "Ray Tracing Animated Scenes using
#: Coherent Grid Traversal"), quoted in summaries
PAPER_FPS = ("Ize et al. 2006 (16 threads, 8 dual-core Opteron 880, rebuild + ray cast): Thai (~10M triangles) "
            "0.78 -> 2.86 fps, Marbles 0.50 -> 1.97 fps, Hand (16k) 78 -> 150 fps.  CGT (Wald et al. 2006, "
            "1024x1024, grid rebuilt every frame, dual 3.2 GHz Xeon, primary rays): Hand 34.5 fps, Marbles "
            "57.1 fps, Fairy forest (174k) 3.4 fps.")


def add_parser(sub):
    p = sub.add_parser("bench", help="benchmarks: CSV + PNG plots + summary.md (medians after warm-up)",
                       description=__doc__.split("\n\n")[0])
    bsub = p.add_subparsers(dest="bench", required=True)

    def common(q, out, runs=5, warmup=1, scenes=None):
        """The options every benchmark has; ``scenes`` = (defaults, fallback) adds --scenes."""
        q.add_argument("--runs", type=int, default=runs, help=f"timed runs per figure, median reported (default {runs})")
        q.add_argument("--warmup", type=int, default=warmup, help=f"untimed runs first (default {warmup})")
        q.add_argument("--out", default=f"out/bench_{out}", help=f"output folder (default out/bench_{out})")
        q.add_argument("--quick", action="store_true", help="tiny scenes and sizes, one run (smoke test)")
        q.add_argument("--no-progress", action="store_true", help="no progress bars")
        if scenes:
            q.add_argument("--scenes", default=None, help=scenes_help(*scenes))

    c = bsub.add_parser("core", help="serial build ms (bbox, exact) and primary-ray Mrays/s on ~100k and ~1M triangles")
    common(c, "core", scenes=(CORE_SCENES, CORE_FALLBACK))
    c.add_argument("--size", type=int, default=1024, help="square image edge for the ray figures (default 1024)")
    c.add_argument("--threads", default=None, help="thread counts for the ray figures (default: 1 and all cores)")
    c.add_argument("--traversal", default=",".join(TRAVERSALS), help=f"ray traversals, comma-separated of "
                   f"{', '.join(TRAVERSALS)} (default {','.join(TRAVERSALS)}: DDA and CGT side by side)")
    c.set_defaults(func=run_core)

    b = bsub.add_parser("build", help="build strategies x threads x scenes, total and per stage")
    common(b, "build", warmup=2, scenes=(BUILD_SCENES, BUILD_FALLBACK))
    b.add_argument("--strategies", default=None, help="comma-separated strategy names (default: all)")
    b.add_argument("--threads", default=None, help="thread counts (default: 1 .. all cores)")
    g = defaults(GridParams)
    b.add_argument("--insert", choices=INSERT_MODES, default=g["insert"],
                   help=f"insertion test (default {g['insert']})")
    b.add_argument("--lambda", dest="density", type=float, default=g["density"],
                   help=f"grid density (default {g['density']:g})")
    b.add_argument("--macro", type=int, default=g["macro"], help=f"macro-cell edge in cells (default {g['macro']})")
    add_grid_kind_args(b)
    b.add_argument("--size", type=int, default=BUILD_RENDER_SIZE,
                   help="square image edge of a render of each configuration's last grid, for its render ms, tests "
                        f"and cells per ray (0: no render; default {BUILD_RENDER_SIZE})")
    b.add_argument("--back-to-back", action="store_true",
                   help="build each configuration's frames in a row, as a viewer rebuilds with one builder (its "
                        "buffers stay in cache); default: strategies round-robin, fairer under host noise but "
                        "every build of a large scene starts with its buffers out of cache")
    add_cluster_args(b, "configurations (each measured whole by one worker, its builds back to back)")
    b.set_defaults(func=run_build)

    f = bsub.add_parser("frame", help="rebuild + render per frame at 1024x1024 per scene, 1 thread and all cores")
    common(f, "frame", warmup=2, scenes=(FRAME_SCENES, FRAME_FALLBACK))
    f.add_argument("--threads", default=None, help="thread counts (default: 1 and all cores)")
    f.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    f.add_argument("--strategy", default="auto",
                   help="build strategy (default auto: serial at 1 thread, sort_middle above)")
    f.add_argument("--traversal", default=FRAME_TRAVERSAL, help=f"comma-separated of {', '.join(TRAVERSALS)} (default "
                   f"{FRAME_TRAVERSAL}: the packet traversal the fps figures of Ize et al. 2006 and CGT used; single-ray DDA "
                   "takes seconds per frame on some scenes)")
    f.add_argument("--split", choices=("both", "on", "off"), default="both",
                   help="static/moving split for scenes with static parts (default both: measure on and off)")
    f.add_argument("--shading", choices=SHADING_MODES, default="lambert",
                   help="shading of the rendered frames (default %(default)s)")
    f.add_argument("--dt", type=float, default=1.0 / 30.0, help="seconds between frames (default 1/30)")
    add_grid_kind_args(f)
    add_packet_args(f)
    add_cluster_args(f, "configurations (each measured whole by one worker)")
    f.set_defaults(func=run_frame)

    from . import cluster_bench as bench_cluster
    from . import looks as bench_looks, packets as bench_packets, peers as bench_peers, start as bench_start
    from . import trade as bench_trade

    bench_trade.add_parser(bsub, common)
    bench_peers.add_parser(bsub, common)
    bench_start.add_parser(bsub, common)
    bench_packets.add_parser(bsub, common)
    bench_looks.add_parser(bsub, common)
    bench_cluster.add_parser(bsub, common)
    return p


# ----------------------------------------------------------------------------------------------
# core
# ----------------------------------------------------------------------------------------------

CORE_ALIASES = {"bunny16": "bunny:1000000", "ico82k": "icosphere:81920", "ico1m": "icosphere:1310720"}
CORE_SCENES = ["lucy", "bunny:1000000"]
CORE_FALLBACK = ["icosphere:81920", "icosphere:1310720"]


def timings(fn, runs, warmup=1):
    """(median, min, max) ms of ``runs`` calls of fn after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return stat(ts)


def _one_shot_rows(tris, label, runs, warmup):
    """One-shot builds against a reused builder's rebuild of the same triangles (serial strategy, one
    thread, default parameters), timed in turns so that load falls on all alike: build_grid of the
    float32 and of the float64 triangles, RayCaster over them as a triangle soup (3 vertices per
    triangle) and that caster's update (its reused builder)."""
    from gridrt.api import RayCaster
    from gridrt.grid.build import build_grid

    p = GridParams(strategy="serial", threads=1)
    t64 = tris.astype(np.float64)
    v, f = tris.reshape(-1, 3), np.arange(3 * len(tris), dtype=np.int32).reshape(-1, 3)
    builder = GridBuilder(p)
    caster = RayCaster(v, f, p)
    cases = [("reused builder rebuild", lambda: builder.build(tris)),
             ("one-shot build_grid float32", lambda: build_grid(tris, p)),
             ("one-shot build_grid float64", lambda: build_grid(t64, p)),
             ("one-shot RayCaster (soup)", lambda: RayCaster(v, f, p)),
             ("RayCaster.update (soup)", lambda: caster.update(v))]
    for _, fn in cases:
        for _ in range(warmup):
            fn()
    ts = [[] for _ in cases]
    for _ in range(runs):
        for (_, fn), t in zip(cases, ts):
            t0 = time.perf_counter()
            fn()
            t.append((time.perf_counter() - t0) * 1e3)
    meds = [stat(t) for t in ts]
    return [dict(scene=label, triangles=len(tris), what=what, threads=1, median_ms=med, min_ms=lo, max_ms=hi,
                 references="", refs_per_tri="", cells="", mtris_per_s=len(tris) / med / 1e3, mrays="",
                 vs_rebuild=med / meds[0][0])
            for (what, _), (med, lo, hi) in zip(cases, meds)]


def run_core(a):
    check_runs(a.runs, a.warmup)
    if a.size < 1:
        raise InputError(f"--size must be positive, got {a.size}")
    size = 64 if a.quick else a.size
    runs = 1 if a.quick else a.runs
    text = ",".join(CORE_ALIASES.get(s.strip(), s.strip()) for s in a.scenes.split(",")) if a.scenes else None
    specs, note = scene_list(text, CORE_SCENES, CORE_FALLBACK,
                             quick=["icosphere:1280"] if a.quick else None)
    threads = thread_list(a.threads)
    travs = [t.strip() for t in a.traversal.split(",") if t.strip()]
    for t in travs:
        if t not in TRAVERSALS:
            raise InputError(f"unknown traversal {t!r}; choose from {', '.join(TRAVERSALS)}")
    out = out_dir(a.out)
    info = machine_info(threads)
    print(f"machine: {info['cpu']}, {info['cores']} cores, numba {info['numba']}, numpy {info['numpy']}",
          file=sys.stderr)
    if note:
        print(f"note: {note}", file=sys.stderr)
    rows = []
    bar = progress(len(specs) * (3 + len(threads) * len(travs)), "bench core", a.no_progress)
    for spec in specs:
        sc = resolve_scene(spec)
        tris = np.array(sc.scene.triangles_at(0.0, origin=sc.scene.frame_origin(0.0)))  # as the pipeline grids it
        label = f"{sc.label} ({sc.scene.name})" if sc.label != sc.scene.name else sc.label
        for ins in ("bbox", "exact"):
            b = GridBuilder(GridParams(strategy="serial", insert=ins, threads=1))
            med, lo_, hi_ = timings(lambda: b.build(tris), runs, a.warmup)
            g = b.build(tris)
            rows.append(dict(scene=label, triangles=len(tris), what=f"serial build {ins}", threads=1,
                             median_ms=med, min_ms=lo_, max_ms=hi_, references=g.references,
                             refs_per_tri=g.references / len(tris), cells=g.spec.n_cells,
                             mtris_per_s=len(tris) / med / 1e3, mrays=""))
            bar.update()
        rows += _one_shot_rows(tris, label, runs, a.warmup)
        bar.update()
        g = GridBuilder(GridParams(strategy="serial", threads=1)).build(tris)
        cam = facing_camera(g.spec.scene_lo, g.spec.scene_hi)
        for th, tv in ((th, tv) for th in threads for tv in travs):
            r = Renderer()
            rp = RenderParams(size, size, threads=th, traversal=tv)
            med, lo_, hi_ = timings(lambda: r.render(g, tris, cam, rp), runs, a.warmup)
            res = r.render(g, tris, cam, rp)
            rows.append(dict(scene=label, triangles=len(tris), what=f"primary rays {size}x{size} {tv}", threads=th,
                             traversal=tv,
                             median_ms=med, min_ms=lo_, max_ms=hi_, references=g.references,
                             refs_per_tri=g.references / len(tris), cells=g.spec.n_cells, mtris_per_s="",
                             mrays=size * size / med / 1e3, hit_fraction=res.stats["hit_fraction"],
                             tests_per_ray=res.stats["tests_per_ray"]))
            bar.update()
    bar.close()
    finish_machine(info)
    write_csv(rows, out / "core.csv")
    write_json(info, out / "machine.json")
    _plot_core(rows, out / "core.png")
    table = []
    for r in rows:
        extra = (f"{r['mtris_per_s']:.1f} Mtri/s" if r["mtris_per_s"] != "" else
                 f"{r['mrays']:.2f} Mrays/s (hit fraction {r['hit_fraction']:.2f}, {r['tests_per_ray']:.1f} tests/ray)")
        if "vs_rebuild" in r:
            extra += f", {r['vs_rebuild']:.2f}x the reused rebuild"
        refs = f"{r['refs_per_tri']:.2f}" if r["refs_per_tri"] != "" else ""
        table.append([r["scene"], f"{r['triangles']:,}", r["what"], r["threads"],
                      f"{r['median_ms']:.1f} [{r['min_ms']:.1f}-{r['max_ms']:.1f}]", refs, extra])
    body = md_table(["scene", "triangles", "what", "threads", "ms median [min-max]", "refs/tri", "rate"], table)
    body += ["", f"Medians of {runs} runs after {a.warmup} warm-up run(s).  Build: strategy serial, 1 thread, "
             "lambda 4, macro 4.  Rays: one primary ray per pixel, camera along the mesh's thinnest axis, "
             "lambert shading, watertight test; dda: single-ray 3D DDA, cgt: coherent grid traversal of 8x8 "
             "ray packets (Wald et al. 2006), same image.  Ize et al. 2006's serial bounding-box build of the 282k Conference "
             "took 82 ms on one 2006 Opteron core (about 3.4M triangles/s)."]
    if note:
        body += ["", f"Note: {note}."]
    write_summary(out / "summary.md", "gridrt bench core", info, [("Results", body), ("Figures", ["![core](core.png)"])])
    print(f"{'scene':24s} {'tris':>9s} {'what':28s} {'thr':>3s} {'median ms':>10s} {'min':>8s} {'max':>8s} "
          f"{'refs/tri':>8s} {'Mrays/s':>8s}  (one-shot rows: x the reused rebuild instead of refs/tri)")
    for r in rows:
        mr = f"{r['mrays']:.2f}" if r["mrays"] != "" else ""
        refs = f"{r['refs_per_tri']:.2f}" if r["refs_per_tri"] != "" else f"{r['vs_rebuild']:.2f}x"
        print(f"{r['scene'][:24]:24s} {r['triangles']:9d} {r['what']:28s} {r['threads']:3d} {r['median_ms']:10.2f} "
              f"{r['min_ms']:8.2f} {r['max_ms']:8.2f} {refs:>8s} {mr:>8s}")
    print(f"medians of {runs} runs after {a.warmup} warm-up; wrote {out}/core.csv, core.png, summary.md")
    return 0


def _plot_core(rows, path):
    fig, ax = figure(1, 2)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    x = np.arange(len(scenes))
    for k, ins in enumerate(("bbox", "exact")):
        ms = [next(r["median_ms"] for r in rows if r["scene"] == s and r["what"] == f"serial build {ins}") for s in scenes]
        ax[0, 0].bar(x + (k - 0.5) * 0.38, ms, 0.38, label=ins)
    ax[0, 0].set_xticks(x, [s[:22] for s in scenes], fontsize=7)
    ax[0, 0].set_ylabel("serial build ms (median)")
    ax[0, 0].set_yscale("log")
    ax[0, 0].legend(fontsize=8)
    ray = [r for r in rows if r["mrays"] != ""]
    variants = list(dict.fromkeys((r["threads"], r.get("traversal", "dda")) for r in ray))
    for k, (th, tv) in enumerate(variants):
        mr = [next((r["mrays"] for r in ray if r["scene"] == s and (r["threads"], r.get("traversal", "dda")) == (th, tv)),
                   0) for s in scenes]
        w = 0.8 / len(variants)
        ax[0, 1].bar(x + (k - (len(variants) - 1) / 2) * w, mr, w, label=f"{th} thread(s) {tv}")
    ax[0, 1].set_xticks(x, [s[:22] for s in scenes], fontsize=7)
    ax[0, 1].set_ylabel("primary Mrays/s (median)")
    ax[0, 1].legend(fontsize=8)
    fig.suptitle("bench core")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


# ----------------------------------------------------------------------------------------------
# build
# ----------------------------------------------------------------------------------------------

BUILD_SCENES = ["marbles", "cesium", "lucy", "kitchen", "marbles:1000000", "lucy:1600000"]
BUILD_FALLBACK = ["marbles", "icosphere:81920", "icosphere:1310720"]
#: image edge of the render that gives each `bench build` row its render ms, tests and cells per ray
BUILD_RENDER_SIZE = 256


def run_build(a):
    from gridrt.grid.registry import get_builder, names
    from .sweep import run_build_sweep

    check_runs(a.runs, a.warmup)
    runs, warmup = (1, 2) if a.quick else (a.runs, a.warmup)  # 2: a builder's first build clears nothing
    specs, note = scene_list(a.scenes, BUILD_SCENES, BUILD_FALLBACK, quick=["icosphere:1280"] if a.quick else None)
    if a.strategies:
        strategies = [s.strip() for s in a.strategies.split(",") if s.strip()]
        for s in strategies:
            get_builder(s)
    else:
        strategies = names()
    kinds = grid_kinds(a)
    params = GridParams(density=a.density, macro=a.macro, insert=a.insert, top_density=a.top_density,
                        leaf_density=a.leaf_density)
    if a.size < 0:
        raise InputError(f"--size must be 0 (no render) or positive, got {a.size}")
    if a.threads:
        thread_list(a.threads)  # (checked before a cluster starts)
    size = min(a.size, 64) if a.quick else a.size
    mib = 16 if a.quick else 256
    if wants_cluster(a):
        return _run_build_cluster(a, specs, note, strategies, kinds, params, size, runs, warmup, mib)
    cores = check_threads(None)
    threads = thread_list(a.threads) if a.threads else list(range(1, cores + 1))
    out = out_dir(a.out)
    info = machine_info(threads)
    if note:
        print(f"note: {note}", file=sys.stderr)
    scenes = {}
    for spec in specs:
        sc = resolve_scene(spec)
        scenes[sc.label] = sc.scene
    rows = run_build_sweep(scenes, strategies, threads, runs=runs, warmup=warmup, out_dir=out,
                           progress=not a.no_progress, params=params, interleave=not a.back_to_back, grids=kinds,
                           render=size)
    from gridrt.grid.traffic import stream_bandwidth

    bw = stream_bandwidth(mib, threads, runs=3 if a.quick else 5)
    return _finish_build(a, out, info, rows, scenes, strategies, threads, runs, warmup, params, bw, mib, kinds, size,
                         note)


def _run_build_cluster(a, specs, note, strategies, kinds, params, size, runs, warmup, mib):
    """``bench build`` on a Dask cluster: every configuration (scene, strategy, grid kind,
    threads) measured whole by one worker, its builds back to back (a worker holds one
    configuration at a time; nothing interleaves them)."""
    from . import on_cluster
    from .sweep import plot_methods, plot_steps, write_csv as write_sweep_csv

    out = out_dir(a.out)
    if note:
        print(f"note: {note}", file=sys.stderr)
    with on_cluster.open_cluster(a) as (cl, pressed):
        threads = thread_list(a.threads) if a.threads else list(range(1, on_cluster.worker_cores(cl) + 1))
        info = machine_info(threads)
        info["cluster"] = cl.where
        calls = on_cluster.build_calls(specs, strategies, kinds, threads, params, runs, warmup, size)
        rows, machines = on_cluster.run_configs(cl, calls, "build sweep (cluster)", a.no_progress, pressed=pressed)
        bw, where = on_cluster.stream_on_worker(cl, mib, threads, 3 if a.quick else 5, a.no_progress, pressed)
    info["workers"] = machines
    info["stream_measured_on"] = where
    write_sweep_csv(rows, out / "build_sweep.csv")
    plot_methods(rows, out / "build_methods.png")
    plot_steps(rows, out / "build_steps.png")
    scenes = {r["scene"]: None for r in rows}
    a.back_to_back = True
    return _finish_build(a, out, info, rows, scenes, strategies, threads, runs, warmup, params, bw, mib, kinds, size,
                         note)


def _finish_build(a, out, info, rows, scenes, strategies, threads, runs, warmup, params, bw, mib, kinds, size, note):
    info["stream_gbs"] = {str(t): {k: round(v, 2) for k, v in d.items()} for t, d in bw.items()}
    finish_machine(info)
    write_json(info, out / "machine.json")
    body = _build_summary(rows, scenes, strategies, threads, runs, warmup, params, bw, mib, a.back_to_back, kinds, size)
    if note:
        body += ["", f"Note: {note}."]
    write_summary(out / "summary.md", "gridrt bench build", info,
                  [("Results", body), ("Figures", ["![build methods](build_methods.png)", "",
                                                   "![build steps](build_steps.png)"])])
    for line in body:
        if line.startswith("|") or line.startswith("###"):
            print(line)
    print(f"wrote {out}/build_sweep.csv, build_methods.png, build_steps.png, summary.md")
    return 0


def _build_summary(rows, scenes, strategies, threads, runs, warmup, params, bw, mib, back_to_back=False,
                   kinds=("uniform",), size=0):
    from .sweep import line_label

    order = ("each configuration's builds back to back, one builder, as in a viewer" if back_to_back
             else "strategies interleaved round-robin, so a large scene's buffers are out of cache at each build")
    two_level = f", two-level densities top {params.top_density:g}, leaf {params.leaf_density:g}" if any(
        k != "uniform" for k in kinds) else ""
    body = [f"Grid builds per configuration: {warmup} warm-up + {runs} timed (animated scenes advance 1/30 s "
            f"per build; {order}); insertion {params.insert}, lambda {params.density:g}, "
            f"macro {params.macro}{two_level}; grid {', '.join(kinds)}.  Cells: build ms median [min-max].  "
            f"Speed-up: serial at 1 thread{' (same grid kind)' if len(kinds) > 1 else ''} / this.", ""]
    for sc in scenes:
        rs = [r for r in rows if r["scene"] == sc]
        if not rs:
            continue
        tri = rs[0]["triangles"]
        base = {k: next((r["build_ms"] for r in rs if r["strategy"] == "serial" and r["threads"] == 1
                         and r["grid"] == k), float("nan")) for k in kinds}
        first = {k: next(r for r in rs if r["grid"] == k) for k in kinds}
        sizes = {k: f"{r['references']:,} references, {r['cells']:,} cells" for k, r in first.items()}
        body.append(f"### {sc} ({tri:,} triangles, "
                    + ("; ".join(f"{k}: {v}" for k, v in sizes.items()) if len(kinds) > 1 else sizes[kinds[0]]) + ")")
        body.append("")
        table = []
        for s in strategies:
            for k in kinds:
                row = next((r for r in rs if r["strategy"] == s and r["grid"] == k), None)
                cells = [line_label(row, rows)] if row else [s]
                for t in threads:
                    r = next((r for r in rs if r["strategy"] == s and r["grid"] == k and r["threads"] == t), None)
                    cells.append(fmt_ms(r, "build_ms")
                                 + (f" ({base[k] / r['build_ms']:.2f}x)" if r and r["build_ms"] > 0 else ""))
                table.append(cells)
        body += md_table(["strategy"] + [f"{t} thread(s)" for t in threads], table)
        tmax = max(threads)
        best = min((r for r in rs if r["threads"] == tmax), key=lambda r: r["build_ms"])
        b0 = base[kinds[0]]
        body += ["", f"Fastest at {tmax} thread(s): {line_label(best, rows)} ({best['build_ms']:.1f} ms, "
                 f"{tri / best['build_ms'] / 1e3:.1f} M triangles/s).  Serial at 1 thread"
                 f"{f' ({kinds[0]})' if len(kinds) > 1 else ''}: {b0:.1f} ms ({tri / b0 / 1e3:.1f} M triangles/s).  "
                 f"Stages at {tmax} thread(s), ms median{' (leaf: the two-level leaf passes)' if two_level else ''}:", ""]
        stage = []
        for s in strategies:
            for k in kinds:
                r = next((r for r in rs if r["strategy"] == s and r["grid"] == k and r["threads"] == tmax), None)
                if r:
                    leaf = [f"{sum(r.get(f'leaf_{x}_ms', 0.0) for x in ('res', 'count', 'scatter')):.2f}"]
                    stage.append([line_label(r, rows), f"{r['bounds_ms']:.2f}", f"{r['clear_ms']:.2f}",
                                  f"{r['insert_ms']:.2f}", f"{r['macro_ms']:.2f}", *(leaf if two_level else []),
                                  f"{r['build_ms']:.2f}"])
        body += md_table(["strategy", "bounds", "clear", "insert", "macro", *(["leaf"] if two_level else []), "total"],
                         stage) + [""]
        body += _grid_table(rs, kinds, tmax, size)
    body += _traffic_section(rows, threads, bw, mib)
    return body


def _grid_table(rs, kinds, tmax, size):
    """Per grid kind of one scene, the fastest strategy at tmax threads: what the grid costs and
    what it buys the rays."""
    table = []
    for k in kinds:
        r = min((r for r in rs if r["grid"] == k and r["threads"] == tmax), key=lambda r: r["build_ms"], default=None)
        if r is None:
            continue
        ray = ([fmt_ms(r, "render_ms"), f"{r['tests_per_ray']:.2f}", f"{r['cells_per_ray']:.2f}"] if size else [])
        table.append([k, r["grid_built"], r["strategy"], f"{r['build_ms']:.2f}", f"{r['references']:,}",
                      f"{r['cells']:,}", f"{r['bytes_per_tri']:.1f}", *ray])
    ray = [f"render ms {size}x{size}", "tests/ray", "cells/ray"] if size else []
    return [f"Grid kinds at {tmax} thread(s) (fastest strategy; cells: a two-level grid's leaf cells; render: the "
            "scene's camera, lambert, the default traversal):", "",
            *md_table(["grid", "built", "strategy", "build ms", "references", "cells", "bytes/tri", *ray], table), ""]


def _traffic_section(rows, threads, bw, mib):
    """Bytes moved per build (gridrt.grid.traffic model) against measured streaming bandwidth."""
    body = ["### Memory traffic: bytes moved per build against streaming bandwidth", "",
            f"Sequential streaming bandwidth over {mib} MiB, numba kernels, each thread its own part (GB/s):", ""]
    body += md_table(["threads", "read", "write", "copy (read + write)"],
                     [[str(t), f"{bw[t]['read']:.1f}", f"{bw[t]['write']:.1f}", f"{bw[t]['copy']:.1f}"]
                      for t in threads])
    modelled = [r for r in rows if r.get("model_mb")]
    if not modelled:
        return body + ["", "No modelled build in this sweep (model: serial, counting, sort_middle, bbox insertion)."]
    big = max(r["triangles"] for r in modelled)
    for sc in dict.fromkeys(r["scene"] for r in modelled if r["triangles"] >= min(big, 500_000)):
        body += _traffic_scene(rows, sc, threads, bw)
    return body


def _traffic_scene(rows, sc, threads, bw):
    from gridrt.grid.traffic import MODELLED

    body = ["", f"#### {sc}", "", "Bytes each stage reads and writes (engine/grid/traffic.py counts every array "
            "element once per pass that touches it, so it is a floor), the time measured, and the rate that "
            "makes.  'floor ms' = bytes / the copy bandwidth at that thread count: the time the stage would take "
            "if memory bandwidth were its only limit.", ""]
    def row(strategy, t):
        return next((r for r in rows if r["scene"] == sc and r["strategy"] == strategy and r["threads"] == t
                     and r.get("model_mb")), None)

    def rate(r, t):
        gbs = r["model_mb"] / r["build_ms"]
        return (f"moving {r['model_mb']:.0f} MB in {r['build_ms']:.1f} ms = {gbs:.1f} GB/s against "
                f"{bw[t]['copy']:.1f} GB/s of copy bandwidth ({gbs / bw[t]['copy'] * 100:.0f}%)")

    table = []
    for s in MODELLED:
        for t in threads if s != "serial" else threads[:1]:  # serial runs one thread whatever it is given
            r = row(s, t)
            if r is None:
                continue
            stages = [k[:-3] for k in r if k.endswith("_mb") and k != "model_mb"]
            for st in stages + ["build"]:
                mb = r["model_mb"] if st == "build" else r[st + "_mb"]
                ms = r[st + "_ms"]
                table.append([s if st == stages[0] else "", str(t) if st == stages[0] else "",
                              "**total**" if st == "build" else st, f"{mb:.1f}", f"{ms:.2f}",
                              f"{mb / ms:.1f}" if ms > 0 else "-", f"{mb / bw[t]['copy']:.2f}"])
    body += md_table(["strategy", "threads", "stage", "MB moved", "ms", "GB/s achieved", "floor ms"], table)
    tmax = max(threads)
    ser = row("serial", 1)
    lines = [f"serial at 1 thread: {rate(ser, 1)}."] if ser is not None else []
    for s in ("counting", "sort_middle"):
        r = row(s, tmax)
        if r is not None and ser is not None:
            lines.append(f"{s} at {tmax} threads: {ser['build_ms'] / r['build_ms']:.2f}x serial, {rate(r, tmax)}.")
    body += [""] + [f"- {x}" for x in lines]
    return body


# ----------------------------------------------------------------------------------------------
# frame
# ----------------------------------------------------------------------------------------------

FRAME_TRAVERSAL = defaults(RenderParams)["traversal"]  # the engine's default, the packet traversal (CGT)
FRAME_SCENES = ["marbles", "cesium", "robots", "kitchen", "lucy:twist", "lucy:1600000:twist"]
FRAME_FALLBACK = ["marbles", "icosphere:20480:twist", "icosphere:1310720:twist"]


def _has_split(scene):
    m = getattr(scene, "static_mask", None)
    if m is None or getattr(scene, "static", False):
        return False
    m = np.asarray(m, bool)
    return bool(m.any() and not m.all())


def frame_strategy(name, threads):
    if name == "auto":
        return "serial" if threads == 1 else "sort_middle"
    return name


def frame_pipeline(scene, variant, strategy, size, shading, packet, packet_precision, top_density, leaf_density):
    """The FramePipeline of one ``bench frame`` configuration: variant = (threads, traversal,
    split, grid kind)."""
    from gridrt.pipeline import FramePipeline

    th, tr, sp, gk = variant
    return FramePipeline(scene, GridParams(strategy=frame_strategy(strategy, th), threads=th, grid=gk,
                                           top_density=top_density, leaf_density=leaf_density),
                         RenderParams(size, size, shading=shading, threads=th, traversal=tr, packet=packet,
                                      packet_precision=packet_precision),
                         split_static=sp, follow_camera=True)


def frame_row(sc, pipe, variant, smp, strategy, packet, packet_precision, size, runs):
    """The ``bench frame`` row of one configuration (``sc`` a BenchScene, ``smp`` its timed
    frames' stats)."""
    th, tr, sp, gk = variant
    s = smp[-1]
    row = dict(scene=sc.label, name=sc.scene.name, triangles=s["triangles"],
               moving_triangles=s.get("moving_triangles", s["triangles"]), threads=th,
               strategy=frame_strategy(strategy, th), traversal=tr, split=int(sp and _has_split(sc.scene)),
               packet=f"{packet[0]}x{packet[1]}", packet_precision=packet_precision,
               static=int(bool(sc.scene.static)), size=size, frames=runs, **grid_columns(pipe.grid_params, s))
    for k in ("frame_ms", "build_ms", "render_ms", "anim_ms"):
        put_stat(row, k, [x[k] for x in smp])
    put_stat(row, "build_render_ms", [x["build_ms"] + x["render_ms"] for x in smp])
    row["fps"] = 1e3 / row["frame_ms"]
    row["fps_build_render"] = 1e3 / row["build_render_ms"]
    row["mrays"] = float(np.median([x["mrays"] for x in smp]))
    row["hit_fraction"] = float(np.median([x["hit_fraction"] for x in smp]))
    row["rebuilt"] = float(np.mean([x["rebuilt"] for x in smp]))
    row["tests_per_ray"] = float(np.median([x["tests_per_ray"] for x in smp]))
    row["cells_per_ray"] = float(np.median([x["cells_per_ray"] for x in smp]))
    return row


def run_frame(a):
    check_frame_args(a)
    travs = [t.strip() for t in a.traversal.split(",") if t.strip()]
    for t in travs:
        if t not in TRAVERSALS:
            raise InputError(f"unknown traversal {t!r}; choose from {', '.join(TRAVERSALS)}")
    size = 64 if a.quick else a.size
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    packet = RenderParams(packet=a.packet).packet  # (checked here, before any scene loads)
    kinds = grid_kinds(a)
    specs, note = scene_list(a.scenes, FRAME_SCENES, FRAME_FALLBACK, quick=["marbles:500"] if a.quick else None)
    threads = thread_list(a.threads)
    if wants_cluster(a):
        return _run_frame_cluster(a, specs, note, travs, kinds, size, runs, warmup, packet)
    out = out_dir(a.out)
    info = machine_info(threads)
    if note:
        print(f"note: {note}", file=sys.stderr)
    scenes = [resolve_scene(s) for s in specs]
    plan = []
    for sc in scenes:
        splits = _split_choices(a, _has_split(sc.scene))
        for th in threads:
            for tr in travs:
                for sp in splits:
                    plan += [(sc, th, tr, sp, gk) for gk in kinds]
    rows = []
    bar = progress(len(plan) * (runs + warmup), "bench frame", a.no_progress)
    for sc in scenes:
        # all variants of one scene advance frame by frame together (round-robin), so load from
        # other processes hits them alike
        variants = [(th, tr, sp, gk) for s2, th, tr, sp, gk in plan if s2 is sc]
        pipes = [frame_pipeline(sc.scene, v, a.strategy, size, a.shading, packet, a.packet_precision, a.top_density,
                                a.leaf_density) for v in variants]
        samples = [[] for _ in variants]
        bar.set_postfix_str(sc.label)
        for i in range(warmup + runs):
            for pipe, smp in zip(pipes, samples):
                fr = pipe.step(i * a.dt)
                if i >= warmup:
                    smp.append(fr.stats)
                bar.update()
        for pipe, v, smp in zip(pipes, variants, samples):
            rows.append(frame_row(sc, pipe, v, smp, a.strategy, packet, a.packet_precision, size, runs))
        del pipes
    bar.close()
    return _finish_frame(a, out, info, rows, size, runs, warmup, note)


def _split_choices(a, has_split):
    return {"both": [True, False], "on": [True], "off": [False]}[a.split] if has_split else [True]


def _run_frame_cluster(a, specs, note, travs, kinds, size, runs, warmup, packet):
    """``bench frame`` on a Dask cluster: every configuration (scene, threads, traversal, split,
    grid kind) runs its warm-up and timed frames whole on one worker."""
    from . import on_cluster

    out = out_dir(a.out)
    if note:
        print(f"note: {note}", file=sys.stderr)
    with on_cluster.open_cluster(a) as (cl, pressed):
        threads = thread_list(a.threads) if a.threads else sorted({1, on_cluster.worker_cores(cl)})
        info = machine_info(threads)
        info["cluster"] = cl.where
        facts = on_cluster.scene_facts(cl, specs, a.no_progress, pressed)
        plan = [(s, (th, tr, sp, gk)) for s, f in zip(specs, facts) for th in threads for tr in travs
                for sp in _split_choices(a, f["has_split"]) for gk in kinds]
        settings = dict(strategy=a.strategy, size=size, shading=a.shading, packet=packet,
                        packet_precision=a.packet_precision, top_density=a.top_density, leaf_density=a.leaf_density)
        rows, machines = on_cluster.run_configs(cl, on_cluster.frame_calls(plan, settings, runs, warmup, a.dt),
                                                "bench frame (cluster)", a.no_progress, pressed=pressed)
    info["workers"] = machines
    return _finish_frame(a, out, info, rows, size, runs, warmup, note)


def _finish_frame(a, out, info, rows, size, runs, warmup, note):
    finish_machine(info)
    write_csv(rows, out / "frame.csv")
    write_json(info, out / "machine.json")
    _plot_frame(rows, out / "frame.png")
    body = _frame_summary(rows, size, runs, warmup, a.strategy)
    if note:
        body += ["", f"Note: {note}."]
    write_summary(out / "summary.md", "gridrt bench frame", info, [("Results", body), ("Figures", ["![frame](frame.png)"])])
    for line in body:
        if line.startswith("|"):
            print(line)
    print(f"wrote {out}/frame.csv, frame.png, summary.md")
    return 0


def _frame_summary(rows, size, runs, warmup, strategy):
    body = [f"Per frame: the scene at t = i/30 s, grid rebuild (only the moving part when the static/moving split "
            f"is on; nothing for a static scene), one primary ray per pixel at {size}x{size}, lambert shading, "
            f"watertight test.  {warmup} warm-up + {runs} timed frames; ms median [min-max].  Strategy "
            f"{'auto = serial at 1 thread, sort_middle above' if strategy == 'auto' else strategy}.  fps = 1000 / "
            "median frame ms (frame = animation + rebuild + render); the figure of Ize et al. 2006 counts rebuild + ray cast "
            "(fps b+r).", ""]
    table = []
    for r in rows:
        table.append([r["scene"], f"{r['triangles']:,}", f"{r['moving_triangles']:,}", r["threads"], r["traversal"],
                      "on" if r["split"] else "-", _kind(r), fmt_ms(r, "anim_ms"), fmt_ms(r, "build_ms"),
                      fmt_ms(r, "render_ms"), fmt_ms(r, "frame_ms"), f"{r['fps']:.2f}", f"{r['fps_build_render']:.2f}",
                      f"{r['hit_fraction']:.2f}", f"{r['tests_per_ray']:.1f}"])
    body += md_table(["scene", "triangles", "rebuilt", "threads", "traversal", "split", "grid", "anim ms", "build ms",
                      "render ms", "frame ms", "fps", "fps b+r", "hit fraction", "tests/ray"], table)
    body += ["", "Grids (cells and references: a two-level grid's leaf level's; a split scene's: both grids'; "
             "bytes/tri: the grids' bytes per triangle of the scene):", ""]
    body += md_table(["scene", "threads", "traversal", "split", "grid", "top density", "leaf density", "cells",
                      "references", "bytes/tri", "build ms", "render ms", "tests/ray", "cells/ray"],
                     [[r["scene"], r["threads"], r["traversal"], "on" if r["split"] else "-", _kind(r),
                       f"{r['top_density']:g}", f"{r['leaf_density']:g}", f"{r['cells']:,}", f"{r['references']:,}",
                       f"{r['bytes_per_tri']:.1f}", fmt_ms(r, "build_ms"), fmt_ms(r, "render_ms"),
                       f"{r['tests_per_ray']:.1f}", f"{r['cells_per_ray']:.1f}"] for r in rows])
    ths = sorted({r["threads"] for r in rows})
    if len(ths) > 1:
        body += ["", f"Scaling, frame ms at 1 thread / at {ths[-1]} threads:", ""]
        sc_rows = []
        for key in dict.fromkeys((r["scene"], r["traversal"], r["split"], r["grid"]) for r in rows):
            one = next((r for r in rows if (r["scene"], r["traversal"], r["split"], r["grid"]) == key
                        and r["threads"] == ths[0]), None)
            many = next((r for r in rows if (r["scene"], r["traversal"], r["split"], r["grid"]) == key
                         and r["threads"] == ths[-1]), None)
            if one and many:
                sc_rows.append([key[0], key[1], "on" if key[2] else "-", key[3],
                                f"{one['build_ms'] / max(many['build_ms'], 1e-9):.2f}x"
                                if many["build_ms"] > 0 else "-", f"{one['render_ms'] / many['render_ms']:.2f}x",
                                f"{one['frame_ms'] / many['frame_ms']:.2f}x"])
        body += md_table(["scene", "traversal", "split", "grid", "build", "render", "frame"], sc_rows)
    split_rows = []
    for r in rows:
        if r["split"]:
            off = next((x for x in rows if x["scene"] == r["scene"] and x["threads"] == r["threads"]
                        and x["traversal"] == r["traversal"] and x["grid"] == r["grid"] and not x["split"]), None)
            if off:
                split_rows.append([r["scene"], r["threads"], r["traversal"], r["grid"],
                                   f"{r['moving_triangles']:,} of {r['triangles']:,}",
                                   fmt_ms(r, "build_ms"), fmt_ms(off, "build_ms"), fmt_ms(r, "render_ms"),
                                   fmt_ms(off, "render_ms")])
    if split_rows:
        body += ["", "Static/moving split (static triangles gridded once, moving ones rebuilt per frame; the ray "
                 "caster traverses both grids) against a full rebuild:", ""]
        body += md_table(["scene", "threads", "traversal", "grid", "moving", "build ms split", "build ms full",
                          "render ms split", "render ms full"], split_rows)
    travs = [t for t in TRAVERSALS if any(r["traversal"] == t for r in rows)]
    if len(travs) > 1:
        body += ["", f"Render ms by traversal (DDA: one ray at a time; CGT: 8x8 packets, coherent grid traversal); "
                 f"in brackets the speed-up over {travs[0]}:", ""]
        key = ("scene", "threads", "split", "grid")
        body += md_table([*key] + [f"render ms {t}" for t in travs],
                         _side_by_side(rows, "traversal", travs, key, "render_ms"))
    kinds = list(dict.fromkeys(r["grid"] for r in rows))
    if len(kinds) > 1:
        body += ["", f"Grid kinds side by side: frame ms, and in brackets the speed-up over {kinds[0]}:", ""]
        key = ("scene", "threads", "traversal", "split")
        body += md_table([*key] + [f"frame ms {k}" for k in kinds], _side_by_side(rows, "grid", kinds, key, "frame_ms"))
    body += ["", "For reference, on 2006 hardware: " + PAPER_FPS]
    return body


def _side_by_side(rows, knob, values, key, ms):
    """Table rows comparing the ``values`` of ``knob`` among the rows that agree on the ``key``
    columns: those columns, then per value ms median [min-max] and the speed-up over values[0]."""
    out = []
    for k in dict.fromkeys(tuple(r[c] for c in key) for r in rows):
        sel = {r[knob]: r for r in rows if tuple(r[c] for c in key) == k}
        if len(sel) == len(values):
            base = sel[values[0]][ms]
            out.append([("on" if v else "-") if c == "split" else v for c, v in zip(key, k)]
                       + [f"{fmt_ms(sel[v], ms)} ({base / sel[v][ms]:.2f}x)" for v in values])
    return out


def _kind(r):
    """A row's grid kind: the kind asked for, and the kind built where they differ (auto)."""
    return r["grid"] if r["grid"] == r["grid_built"] else f"{r['grid']} ({r['grid_built']})"


def _plot_frame(rows, path):
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    variants = list(dict.fromkeys((r["threads"], r["traversal"], r["split"], r["grid"]) for r in rows))
    kinds = {v[3] for v in variants}
    fig, ax = figure(1, 2, w=6.0)
    x = np.arange(len(scenes))
    w = 0.8 / max(len(variants), 1)
    for k, v in enumerate(variants):
        fps = [next((r["fps"] for r in rows
                     if r["scene"] == s and (r["threads"], r["traversal"], r["split"], r["grid"]) == v), 0)
               for s in scenes]
        ax[0, 0].bar(x + (k - (len(variants) - 1) / 2) * w, fps, w,
                     label=f"{v[0]}T {v[1]}{' split' if v[2] else ''}{f' {v[3]}' if len(kinds) > 1 else ''}")
    ax[0, 0].set_xticks(x, [s[:18] for s in scenes], fontsize=7, rotation=20)
    ax[0, 0].set_ylabel("fps (1000 / median frame ms)")
    ax[0, 0].set_yscale("log")
    ax[0, 0].legend(fontsize=6)
    tmax = max(r["threads"] for r in rows)
    sel = [min((r for r in rows if r["scene"] == s and r["threads"] == tmax), key=lambda r: r["frame_ms"])
           for s in scenes]
    bottom = np.zeros(len(scenes))
    for key, lab in (("anim_ms", "animation"), ("build_ms", "rebuild"), ("render_ms", "render")):
        vals = np.array([r[key] for r in sel])
        ax[0, 1].bar(x, vals, 0.6, bottom=bottom, label=lab)
        bottom += vals
    ax[0, 1].set_xticks(x, [s[:18] for s in scenes], fontsize=7, rotation=20)
    ax[0, 1].set_ylabel(f"ms per frame at {tmax} thread(s), fastest variant")
    ax[0, 1].legend(fontsize=7)
    fig.suptitle(f"bench frame: {sel[0]['size']}x{sel[0]['size']}, median of {sel[0]['frames']} frames")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
