"""``gridrt bench build``: build strategies x thread counts x grid kinds x scenes, total and per
stage (the "Comparison build methods" and "Individual steps" measurements of Ize, Wald,
Robertson, Parker, RT 2006), a render of each configuration's grid (render ms, tests and cells
per ray), and the bytes each stage moves against measured streaming bandwidth.  With
``--workers N`` / ``--scheduler ADDRESS`` the configurations spread over a Dask cluster
(:mod:`gridrt.app.cluster.bench`).

For every scene, strategy and thread count one :class:`~gridrt.grid.GridBuilder` rebuilds the
grid ``warmup + runs`` times, by default round-robin over the strategies (see ``interleave``).
Animated scenes advance one frame (1/30 s) per build, so the clear stage sees a real previous
frame.  The first ``warmup`` builds are dropped (numba compile, pool start-up, buffer growth)
and each stage's median, min and max over the remaining ``runs`` are recorded.
:func:`run_build_sweep` writes ``build_sweep.csv`` plus two plots:

* ``build_methods.png``: median total build ms against threads, one line per strategy, min-max
  band, one panel per scene;
* ``build_steps.png``: median ms of each stage (clear, insert, macro-cell build) against threads,
  one line per strategy, a row of panels per scene.

Grid kinds (``grids``: uniform, two_level, auto) are swept like the strategies, each a line of its
own in the plots; with ``render`` each configuration's last grid is also rendered (its render
ms, tests and cells per ray), so a kind's build cost and what it buys the rays sit in one row.
"""

import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gridrt.config import INSERT_MODES, GridParams
from gridrt.errors import InputError
from gridrt.frame import FrameSpec
from gridrt.grid.build import GridBuilder
from gridrt.grid.registry import get_builder, names as strategy_names
from gridrt.grid.traffic import MODELLED, stage_bytes, stream_bandwidth
from gridrt.threads import check_threads
from gridrt.trace.render import Renderer

from ..cli import defaults, option_help
from ..cluster.scheduler import add_cluster_args, wants_cluster
from .machine import finish_machine, machine_info
from ..cluster.bench import _bench_scene, open_cluster, run_configs, stream_on_worker, worker_cores
from .options import add_grid_kind_args, check_runs, grid_kinds, thread_list
from .output import figure, grid_columns, grid_label, md_table, out_dir, write_csv, write_json, write_summary
from .scenes import BenchScene, resolve_scene, scene_camera, scene_list
from .stats import fmt_ms

#: the three build stages of Ize et al. 2006, in plot order
STAGES = ("clear_ms", "insert_ms", "macro_ms")
#: seconds between the frames of an animated scene in the sweep
FRAME_DT = 1.0 / 30.0


def _scene_items(scenes):
    """[(name, source, SceneSpec or None)] from a mapping, a single scene, or an iterable of scenes /
    (name, scene); a BenchScene (:mod:`~gridrt.app.bench.scenes`) gives its Animation and its
    SceneSpec."""
    if isinstance(scenes, dict):
        items = list(scenes.items())
    elif hasattr(scenes, "triangles_at") or isinstance(scenes, np.ndarray):
        items = [scenes]
    else:
        try:
            items = list(scenes)
        except TypeError:
            raise InputError(
                f"scenes must be a scene, a list of scenes or a dict name -> scene, got {scenes!r}"
            ) from None
    out = []
    for i, it in enumerate(items):
        if isinstance(it, tuple) and len(it) == 2 and isinstance(it[0], str):
            name, src = it
        else:
            src = it
            name = getattr(src, "name", None) or f"scene{i}"
        spec = None
        if isinstance(src, BenchScene):
            src, spec = src.scene, src.spec
        if not (hasattr(src, "triangles_at") or isinstance(src, np.ndarray)):
            raise InputError(
                f"scene {name!r}: expected an Animation (gridrt.scene.make_scene) or an (F,3,3) array, "
                f"got {type(src).__name__}"
            )
        out.append((str(name), src, spec))
    if not out:
        raise InputError("scenes: need at least one scene")
    names = [n for n, _, _ in out]
    if len(set(names)) != len(names):
        raise InputError(f"scene names must be unique, got {names}")
    return out


def _frame(src, i, origin=None):
    """Frame i of a scene (in the frame of ``origin``, as the frame pipeline grids it), or the array."""
    if isinstance(src, np.ndarray):
        return src
    t = 0.0 if getattr(src, "static", False) else i * FRAME_DT
    return src.triangles_at(t, origin=origin)


def _count(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise InputError(f"{name} must be an integer >= {lo}, got {v!r}")
    return int(v)


def run_build_sweep(
    scenes, strategies, threads, runs=5, warmup=2, out_dir=None, progress=True, params=None, interleave=True,
    grids=None, render=0,
):
    """Time grid builds for every scene x strategy x grid kind x thread count.

    scenes      dict name -> Animation/(F,3,3) array, one scene, or a list of scenes or
                (name, scene) pairs; a BenchScene in place of a scene also gives the
                configurations' FrameSpecs its SceneSpec
    strategies  registered strategy names (gridrt.grid.names())
    threads     thread counts (each 1 .. gridrt.threads.max_threads())
    runs        timed builds per configuration (>= 1; the medians are meant over >= 5)
    warmup      untimed builds first (>= 0)
    out_dir     folder for build_sweep.csv, build_methods.png, build_steps.png (None: no files)
    params      a FrameSpec, or a GridParams (a FrameSpec with that grid part and the other parts'
                defaults): its grid part gives density, macro, insert, top_density and
                leaf_density, its render part the render's settings (strategy, threads, grid
                kind, the render's threads and size are each configuration's:
                :func:`build_spec`)
    interleave  True: for each scene and thread count, keep one builder per strategy and grid
                kind and take the builds round-robin (build i of every strategy, then build
                i + 1 ...), so load from other processes on a shared machine hits all strategies
                alike (memory: all strategies' buffers at once).  False: each configuration's
                builds back to back.
    grids       grid kinds (gridrt.config.GRID_KINDS), each swept like a strategy (None: the
                kind of ``params``'s grid)
    render      image edge of a render of each configuration's last grid (the scene's own camera,
                or one along its thinnest axis; ``runs`` timed renders after one untimed; 0: no
                render)

    Returns one dict per configuration: scene, triangles, strategy, threads, cores,
    oversubscribed, insert, density, macro, runs, the grid's columns
    (:func:`gridrt.app.bench.output.grid_columns`: grid, grid_built, top_density, leaf_density,
    cells, references, grid_bytes, bytes_per_tri), and for every timed stage ``<stage>``
    (median), ``<stage>_min``, ``<stage>_max`` in ms (build_ms, bounds_ms, clear_ms, insert_ms,
    macro_ms and the strategy's sub-stages, a two-level grid's leaf stages), plus lock_waits
    (median) when reported; with ``render``, render_size, render_ms (median, min, max),
    tests_per_ray, cells_per_ray and hit_fraction.
    """
    items = _scene_items(scenes)
    if isinstance(strategies, str):
        strategies = [strategies]
    strategies = list(dict.fromkeys(strategies))
    if not strategies:
        raise InputError("strategies: need at least one strategy name")
    for s in strategies:
        get_builder(s)
    if isinstance(threads, (int, np.integer)):
        threads = [threads]
    threads = list(dict.fromkeys(check_threads(t) for t in threads))
    if not threads:
        raise InputError("threads: need at least one thread count")
    runs = _count("runs", runs, 1)
    warmup = _count("warmup", warmup, 0)
    base = FrameSpec(grid=params) if isinstance(params, GridParams) else params
    if base is None:
        base = FrameSpec()
    if not isinstance(base, FrameSpec):
        raise InputError(f"params must be a FrameSpec or a GridParams, got {type(base).__name__}")
    kinds = list(dict.fromkeys([base.grid.grid] if grids is None else ([grids] if isinstance(grids, str) else grids)))
    if not kinds:
        raise InputError("grids: need at least one grid kind")
    for k in kinds:
        base.grid.replace(grid=k)  # (an unknown kind is refused here)
    render = _count("render", render, 0)
    base = _at_size(base, render)

    total = len(items) * len(strategies) * len(kinds) * len(threads)
    bar = None
    if progress:
        bar = tqdm(total=total, desc="build sweep", unit="config")
    cores = os.cpu_count() or 1
    rows = []
    try:
        for scene_name, src, scene in items:
            if interleave:
                by_key = {}
                for T in threads:
                    if bar is not None:
                        bar.set_postfix_str(f"{scene_name} T={T}")
                    group = [build_spec(base, s, T, k, scene) for s in strategies for k in kinds]
                    for spec, row in zip(group, _measure(scene_name, src, group, runs, warmup, cores, render)):
                        by_key[(spec.grid.strategy, spec.grid.grid, T)] = row
                        if bar is not None:
                            bar.update(1)
                rows += [by_key[(s, k, T)] for s in strategies for k in kinds for T in threads]
            else:
                for strat in strategies:
                    for k in kinds:
                        for T in threads:
                            if bar is not None:
                                bar.set_postfix_str(f"{scene_name} {strat} {k} T={T}")
                            spec = build_spec(base, strat, T, k, scene)
                            rows += _measure(scene_name, src, [spec], runs, warmup, cores, render)
                            if bar is not None:
                                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(rows, out / "build_sweep.csv")
        plot_methods(rows, out / "build_methods.png")
        plot_steps(rows, out / "build_steps.png")
    return rows


def _at_size(base, render):
    """``base`` at render x render (unchanged for 0: no render)."""
    return base.resized(render, render) if render else base


def build_spec(base, strategy, threads, kind, scene=None):
    """The FrameSpec of one ``bench build`` configuration: ``base`` (its grid's density, macro,
    insertion test and two-level densities, its render's settings and size) built with
    ``strategy`` on ``threads`` threads as grid ``kind`` and rendered on as many threads; ``scene``:
    its SceneSpec where the caller knows it (else ``base``'s)."""
    spec = base.replace(grid=base.grid.replace(strategy=strategy, threads=threads, grid=kind),
                        render=base.render.replace(threads=threads))
    return spec if scene is None else spec.replace(scene=scene)


def _measure(scene_name, src, group, runs, warmup, cores, render=0):
    """Rows for a group of configurations (FrameSpecs: :func:`build_spec`) built round-robin on the
    same frames (with ``render``: then each one's last grid rendered with its render settings,
    configuration by configuration, through the scene's own camera or one along its thinnest
    axis)."""
    builders = [GridBuilder(spec.grid) for spec in group]
    samples = [[] for _ in group]
    grids = [None] * len(group)
    origin = None if isinstance(src, np.ndarray) else src.frame_origin(0.0)
    for i in range(warmup + runs):
        tris = _frame(src, i, origin)
        for n, (b, smp) in enumerate(zip(builders, samples)):
            g = grids[n] = b.build(tris)
            if i >= warmup:
                smp.append(g.stats)
    figures = [{} for _ in group]
    if render:
        last = warmup + runs - 1
        cam = scene_camera(src, tris, 0.0 if getattr(src, "static", True) else last * FRAME_DT, origin)
        figures = [_render_figures(g, tris, cam, spec.render, runs) for g, spec in zip(grids, group)]
    return [_row(scene_name, spec.grid, smp, runs, cores, fig) for spec, smp, fig in zip(group, samples, figures)]


def _render_figures(grid, tris, cam, rp, runs):
    """The columns of ``runs`` renders of ``grid`` with the RenderParams ``rp``, after one untimed:
    render_size, render_ms (median, min, max), tests_per_ray, cells_per_ray, hit_fraction."""
    renderer, size = Renderer(), rp.width
    res = renderer.render(grid, tris, cam, rp)  # (compiles, sizes the buffers)
    ms = []
    for _ in range(runs):
        t0 = time.perf_counter()
        res = renderer.render(grid, tris, cam, rp)
        ms.append((time.perf_counter() - t0) * 1e3)
    st = res.stats
    return dict(render_size=size, render_ms=float(np.median(ms)), render_ms_min=min(ms), render_ms_max=max(ms),
                tests_per_ray=st.tests_per_ray, cells_per_ray=st.cells_per_ray, hit_fraction=st.hit_fraction)


def _row(scene_name, p, samples, runs, cores, figures=None):
    last = samples[-1]
    row = dict(
        scene=scene_name,
        triangles=int(last["triangles"]),
        strategy=p.strategy,
        threads=int(p.threads),
        cores=cores,
        oversubscribed=int(p.threads > cores),
        insert=p.insert,
        density=p.density,
        macro=p.macro,
        runs=runs,
        **grid_columns(p, last),
    )
    row["references"] = int(np.median([s["references"] for s in samples]))
    keys = ["build_ms", "bounds_ms", *STAGES]
    keys += sorted({k for s in samples for k in s if k.endswith("_ms") and k not in keys})
    for k in keys:
        v = np.array([s.get(k, 0.0) for s in samples], np.float64)
        row[k] = float(np.median(v))
        row[k + "_min"] = float(v.min())
        row[k + "_max"] = float(v.max())
    if any("lock_waits" in s for s in samples):
        row["lock_waits"] = float(np.median([s.get("lock_waits", 0) for s in samples]))
    for k in ("cells_cleared", "cells_inspected", "macro_cells", "bucket_entries", "top_references"):
        if any(k in s for s in samples):
            row[k] = int(np.median([s.get(k, 0) for s in samples]))
    row.update(figures or {})
    # (the traffic model is the uniform grid's: a two-level grid's leaf passes are not modelled)
    model = stage_bytes(row) if row["grid_built"] == "uniform" else None
    if model is not None:
        row["model_mb"] = sum(model.values()) / 1e6
        for k, v in model.items():
            row[k[:-3] + "_mb"] = v / 1e6
    return row


def line_label(r, rows):
    """A row's line in the plots and tables: its strategy, and its grid kind when ``rows`` hold
    more than one."""
    return r["strategy"] + grid_label(r, rows)


def _series(rows, scene, key):
    """{line (strategy, and grid kind when several): (threads, median, min, max)} for one scene and
    one timed key."""
    out = {}
    for r in rows:
        if r["scene"] != scene:
            continue
        vals = (r.get(key, np.nan), r.get(key + "_min", np.nan), r.get(key + "_max", np.nan))
        out.setdefault(line_label(r, rows), []).append((r["threads"], *vals))
    return {s: tuple(np.array(c) for c in zip(*sorted(v))) for s, v in out.items()}


def _draw(ax, series, title, ylabel):
    import matplotlib  # deferred: matplotlib, slow to load; plots only

    colors = matplotlib.colormaps["tab10"]
    styles = ("-", "--", "-.", ":")
    for n, (s, (t, med, lo, hi)) in enumerate(series.items()):
        c = colors(n % 10)
        ax.plot(t, med, marker="o", linestyle=styles[n % 4], color=c, label=s, markersize=3, linewidth=1.3)
        ax.fill_between(t, lo, hi, color=c, alpha=0.07, linewidth=0)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("threads")
    ax.set_ylabel(ylabel)
    ts = sorted({int(x) for v in series.values() for x in v[0]})
    ax.set_xticks(ts)
    vals = np.concatenate([v[1] for v in series.values()])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if len(vals) and vals.max() / vals.min() > 20:
        ax.set_yscale("log")
    ax.grid(True, alpha=0.3)


def _legend(fig, axes):
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0, 0.85, 0.95))
    fig.legend(handles, labels, loc="center right", fontsize=8, frameon=False)


def _scenes(rows):
    seen = []
    for r in rows:
        if r["scene"] not in seen:
            seen.append(r["scene"])
    return seen


def plot_methods(rows, path):
    """Median total build ms against threads, one line per strategy (min-max band), per scene."""
    scenes = _scenes(rows)
    ncols = min(len(scenes), 3)
    nrows = math.ceil(len(scenes) / ncols)
    fig, axes = figure(nrows, ncols, w=4.6, h=3.4)
    for n, sc in enumerate(scenes):
        ax = axes[n // ncols, n % ncols]
        tri = next(r["triangles"] for r in rows if r["scene"] == sc)
        _draw(ax, _series(rows, sc, "build_ms"), f"{sc} ({tri:,} triangles)", "build ms (median)")
    for n in range(len(scenes), nrows * ncols):
        axes[n // ncols, n % ncols].set_visible(False)
    _legend(fig, axes)
    fig.suptitle("Comparison build methods (median of the timed builds, band: min..max)")
    fig.savefig(path, dpi=110, bbox_inches="tight")


def plot_steps(rows, path):
    """Median ms of each stage (clear, insert, macro) against threads, per strategy and scene."""
    scenes = _scenes(rows)
    fig, axes = figure(len(scenes), len(STAGES), w=4.6, h=3.4)
    for n, sc in enumerate(scenes):
        for m, st in enumerate(STAGES):
            _draw(axes[n, m], _series(rows, sc, st), f"{sc}: {st[:-3]}", "ms (median)")
    _legend(fig, axes)
    fig.suptitle("Individual steps (median, band: min..max)")
    fig.savefig(path, dpi=110, bbox_inches="tight")


BUILD_SCENES = ["marbles", "cesium", "lucy", "kitchen", "marbles:1000000", "lucy:1600000"]
BUILD_FALLBACK = ["marbles", "icosphere:81920", "icosphere:1310720"]
#: image edge of the render that gives each `bench build` row its render ms, tests and cells per ray
BUILD_RENDER_SIZE = 256


def add_parser(bsub, common):
    p = bsub.add_parser("build", help="build strategies x threads x scenes, total and per stage")
    common(p, "build", warmup=2, scenes=(BUILD_SCENES, BUILD_FALLBACK))
    p.add_argument("--strategies", default=None, help="comma-separated strategy names (default: all)")
    p.add_argument("--threads", default=None, help=option_help("--threads", "every count from 1 to all cores",
                                                               several=True))
    g = defaults(GridParams)
    p.add_argument("--insert", choices=INSERT_MODES, default=g["insert"], help=option_help("--insert"))
    p.add_argument("--lambda", dest="density", type=float, default=g["density"], help=option_help("--lambda"))
    p.add_argument("--macro", type=int, default=g["macro"], help=option_help("--macro"))
    add_grid_kind_args(p)
    p.add_argument("--size", type=int, default=BUILD_RENDER_SIZE,
                   help="square image edge of a render of each configuration's last grid, for its render ms, tests "
                        f"and cells per ray (0: no render; default {BUILD_RENDER_SIZE})")
    p.add_argument("--back-to-back", action="store_true",
                   help="build each configuration's frames in a row, as a viewer rebuilds with one builder (its "
                        "buffers stay in cache); default: strategies round-robin, fairer under host noise but "
                        "every build of a large scene starts with its buffers out of cache")
    add_cluster_args(p, "configurations (each measured whole by one worker, its builds back to back)")
    p.set_defaults(func=run_build)


def run_build(a):
    check_runs(a.runs, a.warmup)
    runs, warmup = (1, 2) if a.quick else (a.runs, a.warmup)  # 2: a builder's first build clears nothing
    specs, note = scene_list(a.scenes, BUILD_SCENES, BUILD_FALLBACK, quick=["icosphere:1280"] if a.quick else None)
    if a.strategies:
        strategies = [s.strip() for s in a.strategies.split(",") if s.strip()]
        for s in strategies:
            get_builder(s)
    else:
        strategies = strategy_names()
    kinds = grid_kinds(a)
    base = build_base(a)
    if a.size < 0:
        raise InputError(f"--size must be 0 (no render) or positive, got {a.size}")
    if a.threads:
        thread_list(a.threads)  # (checked before a cluster starts)
    size = min(a.size, 64) if a.quick else a.size
    mib = 16 if a.quick else 256
    if wants_cluster(a):
        return _run_build_cluster(a, specs, note, strategies, kinds, base, size, runs, warmup, mib)
    cores = check_threads(None)
    threads = thread_list(a.threads) if a.threads else list(range(1, cores + 1))
    out = out_dir(a.out)
    info = machine_info(threads, probe=not a.quick)
    if note:
        print(f"note: {note}", file=sys.stderr)
    scenes = {}
    for spec in specs:
        sc = resolve_scene(spec)
        scenes[sc.label] = sc
    rows = run_build_sweep(scenes, strategies, threads, runs=runs, warmup=warmup, out_dir=out,
                           progress=not a.no_progress, params=base, interleave=not a.back_to_back, grids=kinds,
                           render=size)
    bw = stream_bandwidth(mib, threads, runs=3 if a.quick else 5)
    return _finish_build(a, out, info, rows, scenes, strategies, threads, runs, warmup, base.grid, bw, mib, kinds,
                         size, note)


def build_base(a):
    """The FrameSpec every ``bench build`` configuration starts from: the options' grid density
    (--lambda), macro-cell size, insertion test and two-level densities, every other setting the
    engine's default (:func:`build_spec` fills in the scene, strategy, threads, grid kind and the
    render's size)."""
    return FrameSpec(grid=GridParams(density=a.density, macro=a.macro, insert=a.insert, top_density=a.top_density,
                                     leaf_density=a.leaf_density))


def _run_build_cluster(a, specs, note, strategies, kinds, base, size, runs, warmup, mib):
    """``bench build`` on a Dask cluster: every configuration (scene, strategy, grid kind,
    threads) measured whole by one worker, its builds back to back (a worker holds one
    configuration at a time; nothing interleaves them)."""
    out = out_dir(a.out)
    if note:
        print(f"note: {note}", file=sys.stderr)
    with open_cluster(a) as (cl, pressed):
        threads = thread_list(a.threads) if a.threads else list(range(1, worker_cores(cl) + 1))
        info = machine_info(threads, probe=not a.quick)
        info["cluster"] = cl.where
        calls = build_calls(specs, strategies, kinds, threads, base, runs, warmup, size)
        rows, machines = run_configs(cl, calls, "build sweep (cluster)", a.no_progress, pressed=pressed)
        bw, where = stream_on_worker(cl, mib, threads, 3 if a.quick else 5, a.no_progress, pressed)
    info["workers"] = machines
    info["stream_measured_on"] = where
    write_csv(rows, out / "build_sweep.csv")
    plot_methods(rows, out / "build_methods.png")
    plot_steps(rows, out / "build_steps.png")
    scenes = {r["scene"]: None for r in rows}
    a.back_to_back = True
    return _finish_build(a, out, info, rows, scenes, strategies, threads, runs, warmup, base.grid, bw, mib, kinds,
                         size, note)


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


def _build_config(text, wire, runs, warmup, render):
    """One configuration on a worker: the scene of the --scenes entry ``text`` and the FrameSpec
    read back from its wire format ``wire`` (its scene part set to that scene's)."""
    sc = _bench_scene(text)
    spec = FrameSpec.from_wire(wire).replace(scene=sc.spec)
    return _measure(sc.label, sc.scene, [spec], runs, warmup, os.cpu_count() or 1, render)


def build_calls(specs, strategies, kinds, threads, base, runs, warmup, size):
    """The tasks of ``bench build``, in the order a local run lists its rows: each configuration's
    FrameSpec (``base`` at size x size: :func:`build_spec`) in its wire format
    (:meth:`gridrt.frame.FrameSpec.to_wire`), with its --scenes entry."""
    base = _at_size(base, size)
    return [(_build_config, (s, build_spec(base, st, t, k).to_wire(), runs, warmup, size))
            for s in specs for st in strategies for k in kinds for t in threads]
