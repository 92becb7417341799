"""Build-time sweep over strategies and thread counts: the "Comparison build methods" and
"Individual steps" measurements of Ize, Wald, Robertson, Parker, RT 2006.

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

import csv
import math
import os
import time
from pathlib import Path

import numpy as np

from gridrt.config import GridParams
from gridrt.errors import InputError
from gridrt.grid.build import GridBuilder
from gridrt.grid.registry import get_builder
from gridrt.grid.traffic import stage_bytes
from gridrt.threads import check_threads

#: the three build stages of Ize et al. 2006, in plot order
STAGES = ("clear_ms", "insert_ms", "macro_ms")
#: seconds between the frames of an animated scene in the sweep
FRAME_DT = 1.0 / 30.0


def _scene_items(scenes):
    """[(name, source)] from a mapping, a single scene, or an iterable of scenes / (name, scene)."""
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
        if not (hasattr(src, "triangles_at") or isinstance(src, np.ndarray)):
            raise InputError(
                f"scene {name!r}: expected an Animation (gridrt.scene.make_scene) or an (F,3,3) array, "
                f"got {type(src).__name__}"
            )
        out.append((str(name), src))
    if not out:
        raise InputError("scenes: need at least one scene")
    names = [n for n, _ in out]
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
                (name, scene) pairs
    strategies  registered strategy names (gridrt.grid.names())
    threads     thread counts (each 1 .. gridrt.threads.max_threads())
    runs        timed builds per configuration (>= 1; the medians are meant over >= 5)
    warmup      untimed builds first (>= 0)
    out_dir     folder for build_sweep.csv, build_methods.png, build_steps.png (None: no files)
    params      GridParams for density, macro, insert, top_density, leaf_density (strategy,
                threads and grid are overridden)
    interleave  True: for each scene and thread count, keep one builder per strategy and grid
                kind and take the builds round-robin (build i of every strategy, then build
                i + 1 ...), so load from other processes on a shared machine hits all strategies
                alike (memory: all strategies' buffers at once).  False: each configuration's
                builds back to back.
    grids       grid kinds (gridrt.config.GRID_KINDS), each swept like a strategy (None: the
                kind of ``params``)
    render      image edge of a render of each configuration's last grid (the scene's own camera,
                or one along its thinnest axis; ``runs`` timed renders after one untimed; 0: no
                render)

    Returns one dict per configuration: scene, triangles, strategy, threads, cores,
    oversubscribed, insert, density, macro, runs, the grid's columns
    (:func:`gridrt.app.bench.util.grid_columns`: grid, grid_built, top_density, leaf_density,
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
    base = params if params is not None else GridParams()
    if not isinstance(base, GridParams):
        raise InputError(f"params must be a GridParams, got {type(base).__name__}")
    kinds = list(dict.fromkeys([base.grid] if grids is None else ([grids] if isinstance(grids, str) else grids)))
    if not kinds:
        raise InputError("grids: need at least one grid kind")
    for k in kinds:
        base.replace(grid=k)  # (an unknown kind is refused here)
    render = _count("render", render, 0)

    total = len(items) * len(strategies) * len(kinds) * len(threads)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="build sweep", unit="config")
    cores = os.cpu_count() or 1
    rows = []
    try:
        for scene_name, src in items:
            if interleave:
                by_key = {}
                for T in threads:
                    if bar is not None:
                        bar.set_postfix_str(f"{scene_name} T={T}")
                    group = [base.replace(strategy=s, threads=T, grid=k) for s in strategies for k in kinds]
                    for p, row in zip(group, _measure(scene_name, src, group, runs, warmup, cores, render)):
                        by_key[(p.strategy, p.grid, T)] = row
                        if bar is not None:
                            bar.update(1)
                rows += [by_key[(s, k, T)] for s in strategies for k in kinds for T in threads]
            else:
                for strat in strategies:
                    for k in kinds:
                        for T in threads:
                            if bar is not None:
                                bar.set_postfix_str(f"{scene_name} {strat} {k} T={T}")
                            p = base.replace(strategy=strat, threads=T, grid=k)
                            rows += _measure(scene_name, src, [p], runs, warmup, cores, render)
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


def _measure(scene_name, src, group, runs, warmup, cores, render=0):
    """Rows for a group of configurations built round-robin on the same frames (with ``render``:
    then each one's last grid rendered, configuration by configuration)."""
    builders = [GridBuilder(p) for p in group]
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
        from .util import scene_camera

        last = warmup + runs - 1
        cam = scene_camera(src, tris, 0.0 if getattr(src, "static", True) else last * FRAME_DT, origin)
        figures = [_render_figures(g, tris, cam, p, render, runs) for g, p in zip(grids, group)]
    return [_row(scene_name, p, smp, runs, cores, fig) for p, smp, fig in zip(group, samples, figures)]


def _render_figures(grid, tris, cam, p, size, runs):
    """The columns of ``runs`` renders of ``grid`` at size x size on p.threads threads, after one
    untimed: render_size, render_ms (median, min, max), tests_per_ray, cells_per_ray, hit_fraction."""
    from gridrt.config import RenderParams
    from gridrt.trace.render import Renderer

    renderer, rp = Renderer(), RenderParams(size, size, threads=p.threads)
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
    from .util import grid_columns

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


def write_csv(rows, path):
    """Write rows (dicts, possibly with different keys) to a CSV; missing cells are empty."""
    cols = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, restval="")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def line_label(r, rows):
    """A row's line in the plots and tables: its strategy, and its grid kind when ``rows`` hold
    more than one."""
    from .util import grid_label

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
    import matplotlib

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


def _figure(nrows, ncols, w=4.6, h=3.4):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


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
    fig, axes = _figure(nrows, ncols)
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
    fig, axes = _figure(len(scenes), len(STAGES))
    for n, sc in enumerate(scenes):
        for m, st in enumerate(STAGES):
            _draw(axes[n, m], _series(rows, sc, st), f"{sc}: {st[:-3]}", "ms (median)")
    _legend(fig, axes)
    fig.suptitle("Individual steps (median, band: min..max)")
    fig.savefig(path, dpi=110, bbox_inches="tight")
