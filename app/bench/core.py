"""``gridrt bench core``: serial grid build (bbox and exact insertion) and primary-ray Mrays/s (DDA
and CGT) at 1 thread and all cores on a ~100k and a ~1M triangle mesh."""

import sys
import time

import numpy as np

from gridrt.api import RayCaster
from gridrt.config import TRAVERSALS, GridParams
from gridrt.errors import InputError
from gridrt.frame import FrameSpec
from gridrt.grid.build import GridBuilder, build_grid
from gridrt.trace.render import Renderer

from ..cli import option_help
from .machine import finish_machine, machine_info
from .options import check_runs, thread_list
from .output import figure, md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import facing_camera, resolve_scene, scene_list, seen_through
from .stats import stat, timings

CORE_ALIASES = {"bunny16": "bunny:1000000", "ico82k": "icosphere:81920", "ico1m": "icosphere:1310720"}
CORE_SCENES = ["lucy", "bunny:1000000"]
CORE_FALLBACK = ["icosphere:81920", "icosphere:1310720"]


def add_parser(bsub, common):
    p = bsub.add_parser("core", help="serial build ms (bbox, exact) and primary-ray Mrays/s on ~100k and ~1M triangles")
    common(p, "core", scenes=(CORE_SCENES, CORE_FALLBACK))
    p.add_argument("--size", type=int, default=1024, help="square image edge for the ray figures (default 1024)")
    p.add_argument("--threads", default=None,
                   help=option_help("--threads", "1 and all cores; the ray figures only, the builds are serial",
                                    several=True))
    p.add_argument("--traversal", default=",".join(TRAVERSALS), help=option_help("--traversal", several=True))
    p.set_defaults(func=run_core)


#: the insertion tests of the serial build rows
CORE_INSERTS = ("bbox", "exact")


def core_spec(scene, size):
    """The FrameSpec a scene's ``bench core`` rows start from: the SceneSpec ``scene``, built with
    the serial strategy on one thread, every other grid and render setting the engine's default,
    at size x size."""
    return FrameSpec(scene=scene, grid=GridParams(strategy="serial", threads=1)).resized(size, size)


def build_specs(base):
    """The serial build rows' FrameSpecs: ``base`` (:func:`core_spec`) with each of CORE_INSERTS."""
    return [base.replace(grid=base.grid.replace(insert=ins)) for ins in CORE_INSERTS]


def ray_specs(base, cam, threads, traversals):
    """The primary-ray rows' FrameSpecs: ``base`` (:func:`core_spec`) seen through the Camera ``cam``,
    rendered on each of ``threads`` with each of ``traversals`` (the grid stays ``base``'s)."""
    seen = seen_through(base, cam)
    return [seen.replace(render=seen.render.replace(threads=th, traversal=tv)) for th in threads for tv in traversals]


def _one_shot_rows(tris, label, runs, warmup, p):
    """One-shot builds against a reused builder's rebuild of the same triangles with the GridParams
    ``p`` (:func:`core_spec`'s: serial strategy, one thread, default parameters), timed in turns so
    that load falls on all alike: build_grid of the float32 and of the float64 triangles, RayCaster
    over them as a triangle soup (3 vertices per triangle) and that caster's update (its reused
    builder)."""
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
    return [dict(scene=label, triangles=len(tris), what=what, threads=p.threads, median_ms=med, min_ms=lo, max_ms=hi,
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
    info = machine_info(threads, probe=not a.quick)
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
        base = core_spec(sc.spec, size)
        for bspec in build_specs(base):
            b = GridBuilder(bspec.grid)
            med, lo_, hi_ = timings(lambda: b.build(tris), runs, a.warmup)
            g = b.build(tris)
            rows.append(dict(scene=label, triangles=len(tris), what=f"serial build {bspec.grid.insert}",
                             threads=bspec.grid.threads, median_ms=med, min_ms=lo_, max_ms=hi_,
                             references=g.references, refs_per_tri=g.references / len(tris), cells=g.spec.n_cells,
                             mtris_per_s=len(tris) / med / 1e3, mrays=""))
            bar.update()
        rows += _one_shot_rows(tris, label, runs, a.warmup, base.grid)
        bar.update()
        g = GridBuilder(base.grid).build(tris)
        for rspec in ray_specs(base, facing_camera(g.spec.scene_lo, g.spec.scene_hi, base.view.fov), threads, travs):
            r = Renderer()
            cam, rp = rspec.camera(), rspec.render
            med, lo_, hi_ = timings(lambda: r.render(g, tris, cam, rp), runs, a.warmup)
            res = r.render(g, tris, cam, rp)
            th, tv = rp.threads, rp.traversal
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
    ax[0, 0].set_xticks(x, list(scenes), fontsize=7)
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
    ax[0, 1].set_xticks(x, list(scenes), fontsize=7)
    ax[0, 1].set_ylabel("primary Mrays/s (median)")
    ax[0, 1].legend(fontsize=8)
    fig.suptitle("bench core")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
