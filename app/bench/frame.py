"""``gridrt bench frame``: animation + rebuild + render per frame at 1024x1024 for each scene at 1
thread and all cores (Ize et al. 2006's "Total performance", CGT's fps table); CGT traversal by
default (DDA on request), static/moving split on and off, grid kinds side by side (``--grid``).
With ``--workers N`` / ``--scheduler ADDRESS`` the configurations spread over a Dask cluster
(:mod:`gridrt.app.cluster.bench`)."""

import sys

import numpy as np

from gridrt.config import PARALLEL_DEFAULT_STRATEGY, SHADING_MODES, TRAVERSALS, GridParams, RenderParams, resolve_strategy
from gridrt.errors import InputError
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline

from ..cli import add_packet_args, defaults, option_help
from ..cluster.scheduler import add_cluster_args, wants_cluster
from .machine import finish_machine, machine_info
from ..cluster.bench import _bench_scene, open_cluster, run_configs, worker_cores
from .options import add_dt_arg, add_grid_kind_args, check_frame_args, grid_kinds, thread_list
from .output import figure, grid_columns, md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import resolve_scene, scene_list
from .stats import fmt_ms, put_stat

#: the fps figures of Ize et al. 2006 and of CGT (Wald et al. 2006, "Ray Tracing Animated Scenes using
#: Coherent Grid Traversal"), quoted in summaries
PAPER_FPS = ("Ize et al. 2006 (16 threads, 8 dual-core Opteron 880, rebuild + ray cast): Thai (~10M triangles) "
            "0.78 -> 2.86 fps, Marbles 0.50 -> 1.97 fps, Hand (16k) 78 -> 150 fps.  CGT (Wald et al. 2006, "
            "1024x1024, grid rebuilt every frame, dual 3.2 GHz Xeon, primary rays): Hand 34.5 fps, Marbles "
            "57.1 fps, Fairy forest (174k) 3.4 fps.")
FRAME_TRAVERSAL = defaults(RenderParams)["traversal"]  # the engine's default, the packet traversal (CGT)
FRAME_SCENES = ["marbles", "cesium", "robots", "kitchen", "lucy:twist", "lucy:1600000:twist"]
FRAME_FALLBACK = ["marbles", "icosphere:20480:twist", "icosphere:1310720:twist"]


def add_parser(bsub, common):
    p = bsub.add_parser("frame", help="rebuild + render per frame at 1024x1024 per scene, 1 thread and all cores")
    common(p, "frame", warmup=2, scenes=(FRAME_SCENES, FRAME_FALLBACK))
    p.add_argument("--threads", default=None, help=option_help("--threads", "1 and all cores", several=True))
    p.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    p.add_argument("--strategy", default="auto", help=option_help("--strategy"))
    p.add_argument("--traversal", default=FRAME_TRAVERSAL,
                   help=option_help("--traversal", f"{FRAME_TRAVERSAL}, the packet traversal the fps figures of Ize et al. "
                                    "2006 and CGT used; single-ray DDA takes seconds per frame on some scenes",
                                    several=True))
    p.add_argument("--split", choices=("both", "on", "off"), default="both",
                   help="static/moving split for scenes with static parts (default both: measure on and off)")
    p.add_argument("--shading", choices=SHADING_MODES, default="lambert", help=option_help("--shading"))
    add_dt_arg(p)
    add_grid_kind_args(p)
    add_packet_args(p)
    add_cluster_args(p, "configurations (each measured whole by one worker)")
    p.set_defaults(func=run_frame)


def _has_split(scene):
    m = getattr(scene, "static_mask", None)
    if m is None or getattr(scene, "static", False):
        return False
    m = np.asarray(m, bool)
    return bool(m.any() and not m.all())


def base_spec(a, size, packet):
    """The FrameSpec every ``bench frame`` configuration starts from: the options' grid densities,
    shading, packets and time step at size x size, the scene's own camera followed
    (:func:`frame_spec` fills in the scene, threads, strategy, traversal, split and grid kind)."""
    return FrameSpec(grid=GridParams(top_density=a.top_density, leaf_density=a.leaf_density),
                     render=RenderParams(size, size, shading=a.shading, packet=packet,
                                         packet_precision=a.packet_precision),
                     view=ViewSpec(size=(size, size), follow_camera=True, dt=a.dt))


def frame_spec(base, scene, variant, strategy):
    """The FrameSpec of one ``bench frame`` configuration: ``base`` (:func:`base_spec`) with the
    SceneSpec ``scene`` and variant = (threads, traversal, split, grid kind); ``strategy`` a build
    strategy or "auto" (:func:`gridrt.config.resolve_strategy`)."""
    th, tr, sp, gk = variant
    return base.replace(scene=scene, grid=base.grid.replace(strategy=resolve_strategy(strategy, th), threads=th, grid=gk),
                        render=base.render.replace(threads=th, traversal=tr),
                        view=base.view.replace(split_static=sp))


def frame_row(sc, pipe, spec, smp, runs):
    """The ``bench frame`` row of one configuration (``sc`` a BenchScene, ``spec`` its FrameSpec,
    ``smp`` its timed frames' stats)."""
    s = smp[-1]
    g, r = spec.grid, spec.render
    row = dict(scene=sc.label, name=sc.scene.name, triangles=s["triangles"],
               moving_triangles=s.get("moving_triangles", s["triangles"]), threads=g.threads,
               strategy=g.strategy, traversal=r.traversal, split=int(spec.view.split_static and _has_split(sc.scene)),
               packet=f"{r.packet[0]}x{r.packet[1]}", packet_precision=r.packet_precision,
               static=int(bool(sc.scene.static)), size=spec.size[0], frames=runs, **grid_columns(pipe.grid_params, s))
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
    base = base_spec(a, size, packet)
    if wants_cluster(a):
        return _run_frame_cluster(a, specs, note, travs, kinds, size, runs, warmup, base)
    out = out_dir(a.out)
    info = machine_info(threads, probe=not a.quick)
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
        fspecs = [frame_spec(base, sc.spec, (th, tr, sp, gk), a.strategy) for s2, th, tr, sp, gk in plan if s2 is sc]
        pipes = [FramePipeline.from_spec(s, sc.scene) for s in fspecs]
        samples = [[] for _ in fspecs]
        bar.set_postfix_str(sc.label)
        for i in range(warmup + runs):
            for pipe, smp in zip(pipes, samples):
                fr = pipe.step(base.view.time(i))
                if i >= warmup:
                    smp.append(fr.stats)
                bar.update()
        for pipe, s, smp in zip(pipes, fspecs, samples):
            rows.append(frame_row(sc, pipe, s, smp, runs))
        del pipes
    bar.close()
    return _finish_frame(a, out, info, rows, size, runs, warmup, note)


def _split_choices(a, has_split):
    return {"both": [True, False], "on": [True], "off": [False]}[a.split] if has_split else [True]


def _run_frame_cluster(a, specs, note, travs, kinds, size, runs, warmup, base):
    """``bench frame`` on a Dask cluster: every configuration (scene, threads, traversal, split,
    grid kind) runs its warm-up and timed frames whole on one worker, which receives the base
    FrameSpec in its wire format (:meth:`gridrt.frame.FrameSpec.to_wire`)."""
    out = out_dir(a.out)
    if note:
        print(f"note: {note}", file=sys.stderr)
    with open_cluster(a) as (cl, pressed):
        threads = thread_list(a.threads) if a.threads else sorted({1, worker_cores(cl)})
        info = machine_info(threads, probe=not a.quick)
        info["cluster"] = cl.where
        facts = scene_facts(cl, specs, a.no_progress, pressed)
        plan = [(s, (th, tr, sp, gk)) for s, f in zip(specs, facts) for th in threads for tr in travs
                for sp in _split_choices(a, f["has_split"]) for gk in kinds]
        rows, machines = run_configs(cl, frame_calls(plan, base, a.strategy, runs, warmup), "bench frame (cluster)",
                                     a.no_progress, pressed=pressed)
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
            f"{f'auto = serial at 1 thread, {PARALLEL_DEFAULT_STRATEGY} above' if strategy == 'auto' else strategy}.  fps = 1000 / "
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
    ax[0, 0].set_xticks(x, list(scenes), fontsize=7, rotation=20)
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
    ax[0, 1].set_xticks(x, list(scenes), fontsize=7, rotation=20)
    ax[0, 1].set_ylabel(f"ms per frame at {tmax} thread(s), fastest variant")
    ax[0, 1].legend(fontsize=7)
    fig.suptitle(f"bench frame: {sel[0]['size']}x{sel[0]['size']}, median of {sel[0]['frames']} frames")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _scene_facts(text):
    sc = _bench_scene(text)
    return [{"label": sc.label, "has_split": _has_split(sc.scene)}]


def scene_facts(cl, specs, no_progress=False, pressed=lambda: False):
    rows, _ = run_configs(cl, [(_scene_facts, (s,)) for s in specs], "loading scenes", no_progress, unit="scene",
                          pressed=pressed)
    return rows


def _frame_config(text, variant, base_wire, strategy, runs, warmup):
    """One configuration's rows, on a worker: the scene of ``text`` (loaded once per worker), the
    base FrameSpec read back from its wire format (checked on arrival)."""
    sc = _bench_scene(text)
    spec = frame_spec(FrameSpec.from_wire(base_wire), sc.spec, variant, strategy)
    pipe = FramePipeline.from_spec(spec, sc.scene)
    smp = []
    for i in range(warmup + runs):
        fr = pipe.step(spec.view.time(i))
        if i >= warmup:
            smp.append(fr.stats)
    return [frame_row(sc, pipe, spec, smp, runs)]


def frame_calls(plan, base, strategy, runs, warmup):
    """The tasks of ``bench frame``: plan = [(scene text, (threads, traversal, split, kind))], each
    with the base FrameSpec ``base`` as its wire dict."""
    wire = base.to_wire()
    return [(_frame_config, (s, v, wire, strategy, runs, warmup)) for s, v in plan]
