"""``gridrt bench peers``: gridrt against Intel Embree (PyPI ``embreex``), Open3D and Mitsuba 3,
each where installed (an optional extra, skipped with its install command when absent), on the
same animated mesh, the same rays and the same cores, in one run.

Per frame (t = i/30 s) both rebuild from scratch and cast the same rays, rounded to float32 once
and given to both: one per pixel of a size x size image from the scene's camera (view "frame"),
from that camera moved in until at least 90% of the pixels hit ("fill": a sparse view flatters a
grid's empty-space skipping), or as many random rays from inside the scene's bounds ("random"):

* gridrt: ``GridBuilder.build`` + ``cast_rays`` (watertight test; coherent runs of rays as CGT
  packets, the rest through the single-ray DDA: gridrt.trace.batch), ``threads`` threads;
* Embree: a new ``EmbreeScene`` + ``TriangleMesh`` (the "upload": embreex copies the vertices
  element by element in Python-level code, so it is reported apart), ``rtcCommitScene`` (the BVH
  build; triggered by a zero-ray ``run``) and ``run(origins, dirs, output=1)`` on chunks of the
  rays in a thread pool of ``threads`` threads (``run`` releases the GIL around the traversal:
  the measured pool speed-up is reported).  embreex gives no way to set Embree's own thread
  count, so the process is pinned to ``threads`` CPUs with sched_setaffinity for both engines.

With ``--grid uniform,two_level`` gridrt's grid kinds get a row each (the peers measured again
beside each); every row records gridrt's grid (kind, densities, cells, references, bytes per
triangle) and its CGT render's tests and cells per ray.

Also: static cast throughput (Mrays/s, cast only, on the last frame) and hit agreement (same
triangle id and t within 1e-4 relative, or both miss); disagreeing rays are checked against the
brute-force float64 caster to tell which side is right.

Other peers, measured the same way in the same run: Embree with the other scene flag (fast beside
robust, or robust beside ``--embree-fast``), and when installed (optional extras, each named with
its install command when absent; app/bench/sides.py) Open3D's RaycastingScene (``open3d-cpu``) and
Mitsuba 3's CPU variant ``llvm_ad_rgb`` (``mitsuba``, ``drjit``).

``--export DIR`` also writes each scene in the folder format of the native Embree harness
(``../shared/tools/embree-native``; app/bench/harness.py), one folder per scene and camera view: the
frames this run casts, that view's camera and its rays as primary rays, and the random view's rays as
incoherent rays, the very arrays the peers get; ``--export-only`` writes the folders alone.
"""

import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import gridrt  # noqa: F401
from gridrt.config import TRAVERSALS, GridParams, RenderParams, resolve_strategy
from gridrt.errors import InputError
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.grid.build import GridBuilder
from gridrt.trace.render import Renderer, cast_rays

from ..cli import add_packet_args, option_help

from .affinity import Affinity
from .harness import NATIVE_WARMUP, add_export_args, export_arg, export_folder, folder_name
from .machine import finish_machine, machine_info
from .options import add_dt_arg, add_grid_kind_args, check_frame_args, grid_kinds, thread_list
from .output import figure, grid_columns, grid_label, md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import FILL, camera_rays, resolve_scene, scene_list, scenes_help, seen_through
from .stats import fmt_ms, measured, put_stat
from .reference import brute_cast
from .sides import (  # noqa: F401  (INSTALL_HINT)
    INSTALL_HINT, EmbreeFastSide, EmbreeRobustSide, EmbreeSide, MissingPeer, MitsubaSide, Open3DSide,
)

#: peers measured beside Embree when installed (optional extras; each skipped with a message when absent)
OTHER_PEERS = (Open3DSide, MitsubaSide)

#: the default scenes: with the "fill" view, meshes that fill the frame from 20k to 1.3M triangles
PEER_SCENES = ["cesium", "icosphere:20480:twist", "lucy:twist", "kitchen", "icosphere:1310720:twist"]
PEER_FALLBACK = ["marbles", "icosphere:20480:twist", "icosphere:81920:twist", "icosphere:1310720:twist"]
HAVE_CGT = "cgt" in TRAVERSALS
#: the ray sets (--views)
VIEWS = ("frame", "fill", "random")
#: relative t tolerance of hit agreement
T_REL = 1e-4
#: disagreeing rays checked against brute force, at most
CHECK_MAX = 256


def add_parser(bsub, common):
    p = bsub.add_parser("peers", help="the same animated mesh and rays through Embree, Open3D and Mitsuba 3 side by side",
                        description=__doc__.split("\n\n")[0])
    common(p, "peers", warmup=2, scenes=False)
    p.add_argument("--scenes", default=None, help=scenes_help(PEER_SCENES, PEER_FALLBACK))
    p.add_argument("--threads", default=None, help=option_help("--threads", "1 and all cores", several=True))
    p.add_argument("--size", type=int, default=1024, help="camera image edge: size x size rays (default 1024)")
    p.add_argument("--strategy", default="auto", help=option_help("--strategy"))
    p.add_argument("--embree-fast", action="store_true",
                   help="Embree without RTC_SCENE_FLAG_ROBUST (default robust, like gridrt's watertight test)")
    add_dt_arg(p)
    p.add_argument("--views", default=",".join(VIEWS),
                   help="ray sets, comma-separated: frame (the scene's camera, or one framing its bounds), fill "
                        f"(that camera moved in until at least {100 * FILL:.0f}%% of the pixels hit: a sparse view flatters "
                        "a grid), random (origins uniform in the scene's bounds, directions uniform on the sphere)")
    add_grid_kind_args(p)  # (gridrt's grid; each kind a row of its own, the peers measured again beside it)
    add_packet_args(p)  # (gridrt's: the precision applies to its renders and casts)
    add_export_args(p, "no folders")
    p.set_defaults(func=run_peers)


def agreement(t_o, f_o, t_e, f_e):
    """Counts: both_miss, same (same id and |dt| <= T_REL relative), id_differs (both hit other
    triangles), hit_miss (one side misses), t_off (same id, t differs)."""
    both_miss = (f_o < 0) & (f_e < 0)
    both_hit = (f_o >= 0) & (f_e >= 0)
    same_id = both_hit & (f_o == f_e)
    with np.errstate(invalid="ignore"):
        t_ok = np.abs(t_o - t_e) <= T_REL * np.maximum(np.abs(t_o), 1e-30)
    return dict(both_miss=int(both_miss.sum()), same=int((same_id & t_ok).sum()),
                id_differs=int((both_hit & (f_o != f_e)).sum()), hit_miss=int(((f_o < 0) != (f_e < 0)).sum()),
                t_off=int((same_id & ~t_ok).sum()))


def disagreeing(t_o, f_o, t_e, f_e):
    """Indices of the rays on which two tracers' hits (t, triangle id) do not agree as
    :func:`agreement` counts agreement (both miss, or the same id with t within T_REL)."""
    with np.errstate(invalid="ignore"):
        ok = ((f_o < 0) & (f_e < 0)) | ((f_o == f_e) & (f_o >= 0) & (
            np.abs(t_o - t_e) <= T_REL * np.maximum(np.abs(t_o), 1e-30)))
    return np.flatnonzero(~ok)


def right_against(t, f, rt, rf, rt2):
    """Which hits (t, f) are right against the brute force's (rt, rf; rt2 the nearest t of any other
    triangle): the same triangle (or both miss), or a tie within rounding."""
    scale = np.maximum(np.abs(rt), 1e-30)
    with np.errstate(invalid="ignore"):
        tie = (f >= 0) & (rf >= 0) & (np.abs(rt2 - rt) <= 1e-9 * scale) & (np.abs(t - rt) <= 1e-6 * scale)
    return (f == rf) | tie


def _judge(tris, o, d, idx, t_o, f_o, t_e, f_e, threads):
    """Of the disagreeing rays idx (first CHECK_MAX), how many each side got right against
    brute force (:func:`right_against`)."""
    idx = idx[:CHECK_MAX]
    if not len(idx):
        return dict(checked=0, ours_right=0, embree_right=0)
    rt, rf, rt2 = brute_cast(tris, o[idx], d[idx], threads=threads)
    return dict(checked=len(idx), ours_right=int(right_against(t_o[idx], f_o[idx], rt, rf, rt2).sum()),
                embree_right=int(right_against(t_e[idx], f_e[idx], rt, rf, rt2).sum()))


def export_views(views):
    """The camera views a scene is exported with: those of ``views``, or the scene's own camera."""
    return [v for v in views if v != "random"] or ["frame"]


def export_scene(root, sc, size, views, nframes, dt):
    """Write scene ``sc`` in the harness's folder format under ``root``, one folder per camera view
    of :func:`export_views` (named SCENE_VIEW): ``nframes`` frames at t = i dt (as :func:`_time_frames`
    makes them), that view's camera and its rays, and the random view's rays, each as
    :func:`peer_rays` gives them to every tracer. The folders, in order."""
    origin, _, ro32, rd32, _, _ = peer_rays(sc, size, "random")
    # (a copy of each frame: triangles_at may hand back the same buffer at every call)
    frames = np.stack([np.array(sc.scene.triangles_at(i * dt, origin=origin), np.float32) for i in range(nframes)])
    out = []
    for view in export_views(views):
        vorigin, cam, o32, d32, _, _ = peer_rays(sc, size, view)
        assert np.array_equal(vorigin, origin)  # (every view casts in the same frame)
        out.append(export_folder(root / folder_name(f"{sc.label}_{view}"), f"{sc.label} [{view}]", frames, cam,
                                 size, o32, d32, ro32, rd32, dt))
    return out


def run_peers(a):
    check_frame_args(a)
    views = [v.strip() for v in a.views.split(",") if v.strip()]
    for v in views:
        if v not in VIEWS:
            raise InputError(f"unknown view {v!r} in --views; choose from {', '.join(VIEWS)}")
    size = 64 if a.quick else a.size
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    if a.export and size % 8:
        raise InputError(f"--export needs --size a multiple of 8 (the harness casts 8x8 tiles), got {size}")
    export = export_arg(a)
    nframes = max(warmup + runs, NATIVE_WARMUP + 1)   # (the frames exported: the harness times one at least)
    specs, note = scene_list(a.scenes, PEER_SCENES, PEER_FALLBACK, quick=["icosphere:1280:twist"] if a.quick else None)
    if note:
        print(f"note: {note}", file=sys.stderr)
    if a.export_only:
        for spec in specs:
            sc = resolve_scene(spec)
            for folder in export_scene(export, sc, size, views, nframes, a.dt):
                print(f"{folder}: {sc.label}")
        return 0
    others, absent = [], []
    try:
        emb = EmbreeSide(robust=not a.embree_fast)
        extra = ((EmbreeRobustSide if a.embree_fast else EmbreeFastSide),)  # its other scene flag, same run
    except MissingPeer as e:  # an optional extra like the others: the run goes on without it
        emb, extra = None, ()
        absent.append(f"Embree: {e}")
        print(f"note: Embree not measured: {e}", file=sys.stderr)
    for side in extra + OTHER_PEERS:
        try:
            others.append(side())
        except MissingPeer as e:
            absent.append(f"{side.label}: {e}")
            print(f"note: {side.label} not measured: {e}", file=sys.stderr)
    kinds = grid_kinds(a)
    base = peers_spec(a, size)  # (the packet checked here, before any scene loads)
    threads = thread_list(a.threads)
    out = out_dir(a.out)
    info = machine_info(threads, probe=not a.quick)
    if emb is not None:
        info["embree"] = repr(emb.device)
    for peer in others:
        info[peer.name] = peer.version
    scenes = [resolve_scene(s) for s in specs]
    if export is not None:
        for sc in scenes:
            export_scene(export, sc, size, views, nframes, a.dt)
    rows = []
    bar = progress(len(scenes) * len(views) * len(threads) * len(kinds) * (warmup + runs + 1), "bench peers",
                   a.no_progress)
    affinity_ok = True
    for sc, view in ((sc, view) for sc in scenes for view in views):
        origin, cam, o32, d32, o, d = peer_rays(sc, size, view)
        for spec in peer_specs(base, sc.spec, cam, threads, kinds, a.strategy):
            gp, T, prec = spec.grid, spec.render.threads, spec.render.packet_precision
            bar.set_postfix_str(f"{sc.label} {view} T={T} {gp.grid}")
            builder = GridBuilder(gp)
            renderer = Renderer()
            rp, scam = (spec.render, spec.camera()) if HAVE_CGT and view != "random" else (None, None)
            with Affinity(T) as aff, ThreadPoolExecutor(T) as pool:
                affinity_ok &= aff.applied
                frames = _time_frames(sc, origin, builder, renderer, rp, scam, emb, pool, o32, d32, o, d, T,
                                      warmup, runs, spec.view.dt, bar, others, prec)
                static = _time_static(frames, renderer, rp, scam, emb, pool, o32, d32, o, d, T, runs, others, prec)
                bar.update()
            rows.append(_row(sc, T, gp.strategy, aff.applied, size, runs, emb, o, d, frames, static, rp, others, view))
            packet = spec.render.packet
            rows[-1].update(packet=f"{packet[0]}x{packet[1]}", packet_precision=prec,
                            **grid_columns(gp, frames["grid"].stats))
            if rp is not None:  # (the random view has no image: its rays go through cast_rays only)
                img = frames["img"].stats
                rows[-1].update(tests_per_ray=img.tests_per_ray, cells_per_ray=img.cells_per_ray)
    bar.close()
    _write(rows, out, info, emb, runs, warmup, affinity_ok, note, others, absent)
    return 0


def peers_spec(a, size):
    """The FrameSpec every ``bench peers`` configuration starts from: the options' two-level grid
    densities, gridrt's CGT render with the options' packets and their precision, the options'
    time step, at size x size (:func:`peer_specs` fills in the scene, camera, threads, strategy
    and grid kind)."""
    return FrameSpec(grid=GridParams(top_density=a.top_density, leaf_density=a.leaf_density),
                     render=RenderParams(traversal="cgt", packet=a.packet, packet_precision=a.packet_precision),
                     view=ViewSpec(dt=a.dt)).resized(size, size)


def peer_specs(base, scene, cam, threads, kinds, strategy):
    """The FrameSpecs of one scene and view, one per thread count (built and rendered on that many
    threads) and grid kind, in that order: ``base`` (:func:`peers_spec`) with the SceneSpec
    ``scene``, seen through the Camera ``cam`` (None for the random rays: no camera), built with
    ``strategy`` (a build strategy or "auto": :func:`gridrt.config.resolve_strategy`)."""
    if cam is not None:
        base = seen_through(base, cam)
    base = base.replace(scene=scene)
    return [base.replace(grid=base.grid.replace(strategy=resolve_strategy(strategy, T), threads=T, grid=kind),
                         render=base.render.replace(threads=T)) for T in threads for kind in kinds]


def peer_rays(sc, size, view):
    """(frame origin, camera, float32 origins and directions, the same as float64) of a scene for one
    of VIEWS: size x size camera rays, or as many random rays."""
    if view != "random":
        origin, cam, o32, d32, o, d = camera_rays(sc, size, fill=view == "fill")
    else:
        origin = sc.scene.frame_origin(0.0)
        cam = None
        tris0 = np.asarray(sc.scene.triangles_at(0.0, origin=origin), np.float64).reshape(-1, 3)
        rng = np.random.default_rng(20061204)
        o32 = rng.uniform(tris0.min(axis=0), tris0.max(axis=0), (size * size, 3)).astype(np.float32)
        d = rng.normal(size=(size * size, 3))
        d32 = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
        o, d = o32.astype(np.float64), d32.astype(np.float64)
    return origin, cam, o32, d32, o, d


def _time_frames(sc, origin, builder, renderer, rp, cam, emb, pool, o32, d32, o, d, T, warmup, runs, dt, bar,
                 others=(), prec="float64"):
    """Per frame, all rebuild from scratch and cast: {samples (ms lists), last grid, triangles and hits}
    (emb None: Embree is not installed and not measured)."""
    smp = {k: [] for k in ("o_build", "o_cast", "o_frame", "o_render_cgt", "o_frame_cgt", "e_upload",
                           "e_commit", "e_cast", "e_frame", "e_frame_noupload")}
    for peer in others:
        smp.update({f"{peer.name}_{k}": [] for k in ("upload", "commit", "cast", "frame")})
    peer_hits = {}
    img = None
    for i in range(warmup + runs):
        tris = sc.scene.triangles_at(i * dt, origin=origin)
        t0 = time.perf_counter()
        g = builder.build(tris)
        t1 = time.perf_counter()
        ho = cast_rays(g, tris, o, d, threads=T, packet_precision=prec)
        t2 = time.perf_counter()
        if rp is not None:
            img = renderer.render(g, tris, cam, rp)
        t2c = time.perf_counter()
        if emb is not None:
            up, cm = emb.build(tris)
            t3 = time.perf_counter()
            te, fe = emb.cast(pool, o32, d32, T)
            t4 = time.perf_counter()
        for peer in others:
            pu, pc = peer.build(tris)
            t5 = time.perf_counter()
            peer_hits[peer.name] = peer.cast(pool, o32, d32, T)
            pcast = (time.perf_counter() - t5) * 1e3
            if i >= warmup:
                for k, v in (("upload", pu), ("commit", pc), ("cast", pcast), ("frame", pu + pc + pcast)):
                    smp[f"{peer.name}_{k}"].append(v)
        if i >= warmup:
            smp["o_build"].append((t1 - t0) * 1e3)
            smp["o_cast"].append((t2 - t1) * 1e3)
            smp["o_frame"].append((t2 - t0) * 1e3)
            if rp is not None:
                smp["o_render_cgt"].append((t2c - t2) * 1e3)
                smp["o_frame_cgt"].append((t1 - t0 + t2c - t2) * 1e3)
            if emb is not None:
                smp["e_upload"].append(up)
                smp["e_commit"].append(cm)
                smp["e_cast"].append((t4 - t3) * 1e3)
                smp["e_frame"].append(up + cm + (t4 - t3) * 1e3)
                smp["e_frame_noupload"].append(cm + (t4 - t3) * 1e3)
        bar.update()
    if emb is None:
        smp = {k: v for k, v in smp.items() if not k.startswith("e_")}
    return dict(samples=smp, grid=g, tris=tris, hits=ho, embree=(te, fe) if emb is not None else None, img=img,
                peers=peer_hits)


def _time_static(frames, renderer, rp, cam, emb, pool, o32, d32, o, d, T, runs, others=(), prec="float64"):
    """Static cast throughput on the last frame: (gridrt cast ms, Embree cast ms, gridrt CGT render ms)
    lists, and the last CGT image; the other peers' cast ms into frames["static_peers"]."""
    g, tris = frames["grid"], frames["tris"]
    so, se, sr = [], [], []
    sp = frames["static_peers"] = {peer.name: [] for peer in others}
    for _ in range(runs):
        for peer in others:
            t0 = time.perf_counter()
            peer.cast(pool, o32, d32, T)
            sp[peer.name].append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        cast_rays(g, tris, o, d, threads=T, packet_precision=prec)
        t1 = time.perf_counter()
        if emb is not None:
            emb.cast(pool, o32, d32, T)
        t2 = time.perf_counter()
        if rp is not None:
            frames["img"] = renderer.render(g, tris, cam, rp)
        t3 = time.perf_counter()
        so.append((t1 - t0) * 1e3)
        if emb is not None:
            se.append((t2 - t1) * 1e3)
        sr.append((t3 - t2) * 1e3)
    return so, se, sr


def _row(sc, T, strat, pinned, size, runs, emb, o, d, frames, static, rp, others=(), view="frame"):
    """The CSV row of one scene and thread count: timings, throughputs and the two tracers' agreement."""
    last = np.array(frames["tris"])
    ho, img = frames["hits"], frames["img"]
    so, se, sr = static
    N = len(o)
    row = dict(scene=f"{sc.label} [{view}]", name=sc.scene.name, view=view, triangles=len(last), threads=T,
               strategy=strat, cpus=T if pinned else "", rays=N, size=size, frames=runs,
               embree_robust=int(emb.robust) if emb is not None else "", hit_fraction=float((ho.tri >= 0).mean()))
    for k, v in frames["samples"].items():
        put_stat(row, k + "_ms", v)
    put_stat(row, "o_static_cast_ms", so)
    if rp is not None:
        put_stat(row, "o_static_render_cgt_ms", sr)
        row["o_mrays_cgt"] = N / row["o_static_render_cgt_ms"] / 1e3
        row["o_fps_cgt"] = 1e3 / row["o_frame_cgt_ms"]
    row["o_mrays"] = N / row["o_static_cast_ms"] / 1e3
    row["o_fps"] = 1e3 / row["o_frame_ms"]
    if emb is not None:
        te, fe = frames["embree"]
        ag = agreement(ho.t, ho.tri.astype(np.int64), te, fe)
        bad = disagreeing(ho.t, ho.tri, te, fe)
        judge = _judge(last, o, d, bad, ho.t, ho.tri.astype(np.int64), te, fe, T)
        put_stat(row, "e_static_cast_ms", se)
        if rp is not None:
            agc = agreement(img.t.ravel().astype(np.float64), img.tri.ravel().astype(np.int64), te, fe)
            row["agree_cgt"] = (agc["both_miss"] + agc["same"]) / N
        row["e_mrays"] = N / row["e_static_cast_ms"] / 1e3
        row["e_fps"] = 1e3 / row["e_frame_ms"]
        row["e_fps_noupload"] = 1e3 / row["e_frame_noupload_ms"]
        row.update(ag)
        row["agree"] = (ag["both_miss"] + ag["same"]) / N
        row.update(judge)
    for peer in others:
        put_stat(row, f"{peer.name}_static_cast_ms", frames["static_peers"][peer.name])
        row[f"{peer.name}_mrays"] = N / row[f"{peer.name}_static_cast_ms"] / 1e3
        row[f"{peer.name}_fps"] = 1e3 / row[f"{peer.name}_frame_ms"]
        tp, fp = frames["peers"][peer.name]
        agp = agreement(ho.t, ho.tri.astype(np.int64), tp, fp)
        row[f"{peer.name}_agree"] = (agp["both_miss"] + agp["same"]) / N
    return row


def _write(rows, out, info, emb, runs, warmup, affinity_ok, note, others=(), absent=()):
    """peers.csv, machine.json, peers.png and summary.md; the summary's table on stdout."""
    finish_machine(info)
    write_csv(rows, out / "peers.csv")
    write_json(info, out / "machine.json")
    _plot(rows, out / "peers.png", emb is not None)
    body = (_summary(rows, emb, runs, warmup, affinity_ok) if emb is not None else _gridrt_summary(rows, runs, warmup))
    body += _grid_summary(rows)
    body += _others_summary(rows, others, absent)
    if emb is not None and others:
        body += _side_by_side(rows, emb, others)
    if note:
        body += ["", f"Note: {note}."]
    write_summary(out / "summary.md", "gridrt bench peers: gridrt against " + ("Embree and " if emb is not None else "")
                  + "the other peers", info,
                  [("Results", body), ("Figures", ["![peers](peers.png)"])])
    for line in body:
        if line.startswith("|"):
            print(line)
    print(f"wrote {out}/peers.csv, peers.png, summary.md")


def _name(r, rows):
    """A row's scene [view] in the tables, with gridrt's grid kind when the rows hold several."""
    return r["scene"] + grid_label(r, rows)


def _grid_summary(rows):
    """gridrt's grids: the kind, its cells, references and bytes, and what the rays paid in it."""
    body = ["", "gridrt's grids, last frame (cells and references: a two-level grid's leaf level's; tests and cells per "
            "ray: the CGT render's primary rays, none for random rays):", ""]
    return body + md_table(
        ["scene", "threads", "grid", "built", "top density", "leaf density", "cells", "references", "bytes/tri",
         "gridrt build", "gridrt CGT render", "tests/ray", "cells/ray"],
        [[r["scene"], r["threads"], r["grid"], r["grid_built"], f"{r['top_density']:g}", f"{r['leaf_density']:g}",
          f"{r['cells']:,}", f"{r['references']:,}", f"{r['bytes_per_tri']:.1f}", fmt_ms(r, "o_build_ms"),
          fmt_ms(r, "o_render_cgt_ms") if "o_mrays_cgt" in r else "-",
          f"{r['tests_per_ray']:.2f}" if "tests_per_ray" in r else "-",
          f"{r['cells_per_ray']:.2f}" if "cells_per_ray" in r else "-"] for r in rows])


def _packets(rows):
    """How gridrt's packets were set in this run, e.g. "8x8-pixel packets (float64 tests)"."""
    r = rows[0] if rows else {}
    return f"{r.get('packet', '8x8')}-pixel packets ({r.get('packet_precision', 'float64')} triangle tests)"


def _gridrt_summary(rows, runs, warmup):
    """The results without Embree: gridrt's own figures (the other peers follow)."""
    body = [f"Embree was not measured (see below).  Per frame gridrt rebuilds from scratch and casts the same "
            f"float32-rounded rays as the other peers; {warmup} warm-up + {runs} timed frames, ms median [min-max].  "
            "gridrt: build + `cast_rays` (watertight; coherent runs of rays as CGT packets, the rest by DDA); CGT "
            f"render: camera rays in {_packets(rows)} with lambert shading.", ""]
    body += md_table(["scene", "triangles", "threads", "hit fraction", "gridrt build", "gridrt cast", "gridrt frame",
                      "gridrt CGT render", "gridrt frame (CGT)", "cast Mrays/s", "CGT render Mrays/s"],
                     [[_name(r, rows), f"{r['triangles']:,}", r["threads"], f"{r['hit_fraction']:.2f}",
                       fmt_ms(r, "o_build_ms"), fmt_ms(r, "o_cast_ms"), fmt_ms(r, "o_frame_ms"),
                       fmt_ms(r, "o_render_cgt_ms") if "o_mrays_cgt" in r else "-",
                       fmt_ms(r, "o_frame_cgt_ms") if "o_mrays_cgt" in r else "-", f"{r['o_mrays']:.2f}",
                       f"{r['o_mrays_cgt']:.2f}" if "o_mrays_cgt" in r else "-"] for r in rows])
    return body


def _summary(rows, emb, runs, warmup, affinity_ok):
    body = [
        f"{emb.version and 'embreex ' + emb.version}, {repr(emb.device)}; scene flag "
        f"{'RTC_SCENE_FLAG_ROBUST' if emb.robust else 'none (fast)'}.  Per frame both rebuild from scratch and cast "
        f"the same float32-rounded camera rays (one per pixel); {warmup} warm-up + {runs} timed frames, ms median "
        "[min-max].  gridrt: build + `cast_rays` (watertight; coherent runs of rays as CGT packets, the rest by "
        "DDA).  Embree: upload (embreex's `TriangleMesh` "
        "copies vertices element by element in Python-level code; native Embree would share the buffer) + commit "
        "(BVH build) + `run(..., output=1)` on ray chunks in a thread pool.",
        "",
        ("Threads: gridrt gets the thread count directly; Embree's build threads cannot be set through embreex, so "
         "the whole process was pinned to that many CPUs with sched_setaffinity (both engines)." if affinity_ok else
         "Threads: this OS has no sched_setaffinity, so Embree's build used every core at every thread count."),
        "",
    ]
    table = []
    for r in rows:
        table.append([_name(r, rows), f"{r['triangles']:,}", r["threads"], fmt_ms(r, "o_build_ms"), fmt_ms(r, "o_cast_ms"),
                      fmt_ms(r, "o_frame_ms"), fmt_ms(r, "e_upload_ms"), fmt_ms(r, "e_commit_ms"), fmt_ms(r, "e_cast_ms"),
                      fmt_ms(r, "e_frame_ms"), f"{r['o_frame_ms'] / r['e_frame_noupload_ms']:.2f}"])
    body += md_table(["scene", "triangles", "threads", "gridrt build", "gridrt cast", "gridrt frame", "Embree upload",
                      "Embree commit", "Embree cast", "Embree frame", "gridrt / Embree without upload"], table)
    if any("o_mrays_cgt" in r for r in rows):
        body += ["", f"gridrt's CGT render: the same traversal as `cast_rays`' packets, in {_packets(rows)}, with the camera "
                 "rays generated in the kernel (the same pixel-centre rays before their float32 rounding) and lambert "
                 "shading.  Frame = build + CGT render:", ""]
        body += md_table(["scene", "threads", "gridrt CGT render", "gridrt frame (CGT)", "Embree frame without upload",
                          "Embree frame", "gridrt CGT / Embree without upload"],
                         [[_name(r, rows), r["threads"], fmt_ms(r, "o_render_cgt_ms"), fmt_ms(r, "o_frame_cgt_ms"),
                           fmt_ms(r, "e_frame_noupload_ms"), fmt_ms(r, "e_frame_ms"),
                           f"{r['o_frame_cgt_ms'] / r['e_frame_noupload_ms']:.2f}"] for r in rows if "o_mrays_cgt" in r])
    body += ["", "Static cast throughput (cast only, last frame) and hit agreement (same triangle and t within "
             f"{T_REL:g} relative, or both miss); disagreements checked against brute force (up to {CHECK_MAX}):", ""]
    t2 = []
    for r in rows:
        t2.append([_name(r, rows), r["threads"], f"{r['hit_fraction']:.2f}", f"{r['o_mrays']:.2f}",
                   f"{r['o_mrays_cgt']:.2f}" if "o_mrays_cgt" in r else "-", f"{r['e_mrays']:.2f}",
                   f"{100 * r['agree']:.4f}%", f"{100 * r['agree_cgt']:.4f}%" if "agree_cgt" in r else "-",
                   r["id_differs"], r["hit_miss"], r["t_off"],
                   f"{r['ours_right']}/{r['checked']}" if r["checked"] else "-",
                   f"{r['embree_right']}/{r['checked']}" if r["checked"] else "-"])
    body += md_table(["scene", "threads", "hit fraction", "gridrt cast Mrays/s", "gridrt CGT render Mrays/s", "Embree Mrays/s",
                      "agree (cast)", "agree (CGT render)", "other triangle", "hit vs miss", "t differs",
                      "gridrt right", "Embree right"], t2)
    body += ["", "'other triangle', 'hit vs miss', 't differs', 'right': for `cast_rays` against Embree; 'right' "
             "counts the disagreeing rays on which each side matches the brute-force float64 caster."]
    ths = sorted({r["threads"] for r in rows})
    if len(ths) > 1:
        sc_lines = []
        for sc in dict.fromkeys(_name(r, rows) for r in rows):
            one = next(r for r in rows if _name(r, rows) == sc and r["threads"] == ths[0])
            many = next(r for r in rows if _name(r, rows) == sc and r["threads"] == ths[-1])
            sc_lines.append(f"- {sc}: Embree cast {one['e_static_cast_ms'] / many['e_static_cast_ms']:.2f}x, commit "
                            f"{one['e_commit_ms'] / many['e_commit_ms']:.2f}x; gridrt cast "
                            f"{one['o_static_cast_ms'] / many['o_static_cast_ms']:.2f}x, build "
                            f"{one['o_build_ms'] / many['o_build_ms']:.2f}x")
        body += ["", f"Speed-up from {ths[0]} to {ths[-1]} threads (a pool speed-up above 1 shows that embreex's "
                 "`run` releases the GIL):", ""] + sc_lines
    return body


def _others_summary(rows, others, absent):
    """The peers measured beside Embree (its other scene flag; Open3D, Mitsuba 3 when installed), against gridrt."""
    body = []
    if others:
        body += ["", "Other peers, the same frames and rays (per frame: upload + build + cast of all rays; "
                 f"static: cast only, last frame; agreement with gridrt's cast_rays: the same triangle and t within {T_REL:g} "
                 "relative, or both miss). "
                 + "; ".join(f"{p.label} {p.version}" for p in others) + ":", ""]
        table = []
        for r in rows:
            for p in others:
                table.append([_name(r, rows), r["threads"], p.label, fmt_ms(r, f"{p.name}_upload_ms"),
                              fmt_ms(r, f"{p.name}_commit_ms"), fmt_ms(r, f"{p.name}_cast_ms"),
                              fmt_ms(r, f"{p.name}_frame_ms"), f"{r[f'{p.name}_mrays']:.2f}",
                              f"{r['o_mrays']:.2f}", f"{r['o_mrays_cgt']:.2f}" if "o_mrays_cgt" in r else "-",
                              f"{r[f'{p.name}_frame_ms'] / r['o_frame_ms']:.2f}",
                              f"{100 * r[f'{p.name}_agree']:.4f}%"])
        body += md_table(["scene", "threads", "peer", "upload", "build", "cast", "frame", "peer Mrays/s",
                          "gridrt cast Mrays/s", "gridrt CGT Mrays/s", "peer frame / gridrt frame", "agree"], table)
    for line in absent:
        body += ["", f"Not measured: {line}."]
    return body


def _side_by_side(rows, emb, others):
    """Every engine in one row per scene and thread count: static Mrays/s (gridrt's against Embree
    robust and against the best peer) and the dynamic frame (gridrt's build + CGT render against the
    best peer's frame, Embree's without embreex's Python-level upload)."""
    labels = [p.label for p in others]
    main = "Embree (robust)" if emb.robust else "Embree (fast)"
    static, frames = [], []
    for r in rows:
        peers = {main: r["e_mrays"], **{p.label: r[f"{p.name}_mrays"] for p in others}}
        best = max(peers.values())
        cgt = measured(r, "o_mrays_cgt")
        static.append([_name(r, rows), r["threads"], f"{r['hit_fraction']:.2f}", f"{r['o_mrays']:.2f}",
                       f"{cgt:.2f}" if cgt else "-", *(f"{v:.2f}" for v in peers.values()),
                       f"{r['o_mrays'] / r['e_mrays']:.2f}", f"{cgt / best:.2f}" if cgt else "-"])
        if measured(r, "o_frame_cgt_ms") is None:  # no CGT render of these rays (random rays)
            continue
        bare = {main: r["e_frame_noupload_ms"]}
        cells = [f"{r['e_frame_ms']:.1f} ({r['e_frame_noupload_ms']:.1f})"]
        for p in others:
            full = r[f"{p.name}_frame_ms"]
            if p.name.startswith("embree"):
                bare[p.label] = full - r[f"{p.name}_upload_ms"]
                cells.append(f"{full:.1f} ({bare[p.label]:.1f})")
            else:
                bare[p.label] = full
                cells.append(f"{full:.1f}")
        ours = r["o_frame_cgt_ms"]
        frames.append([_name(r, rows), r["threads"], f"{r['o_build_ms']:.1f} + {r['o_render_cgt_ms']:.1f} = {ours:.1f}",
                       *cells, f"{min(bare.values()) / ours:.1f}x", f"{1e3 / ours:.0f}"])
    body = ["", "All engines side by side.  Static cast, Mrays/s (best peer: the fastest of the peers, both of "
            "Embree's scene flags included):", ""]
    body += md_table(["scene", "threads", "hit", "gridrt cast_rays", "gridrt CGT render", main, *labels,
                      f"cast_rays / {main}", "CGT / best peer"], static)
    if frames:
        body += ["", "Dynamic frames, ms (gridrt: build + CGT render; the peers: upload + build + cast of the same "
                 "rays, and in brackets Embree's without embreex's Python-level upload); best peer / gridrt: the best "
                 "peer's frame, Embree's without upload, over gridrt's:", ""]
        body += md_table(["scene", "threads", "gridrt build + CGT render", f"{main} frame (without upload)",
                          *(f"{x} frame" + (" (without upload)" if p.name.startswith("embree") else "")
                            for x, p in zip(labels, others)), "best peer / gridrt", "gridrt fps"], frames)
    return body


def _plot(rows, path, embree=True):
    labels = [f"{r['scene']}\n{r['threads']}T{grid_label(r, rows)}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = figure(1, 2, w=6.0)
    a = ax[0, 0]
    b1 = np.array([r["o_build_ms"] for r in rows])
    c1 = np.array([r["o_cast_ms"] for r in rows])
    a.bar(x - 0.2, b1, 0.4, label="gridrt build", color="C0")
    a.bar(x - 0.2, c1, 0.4, bottom=b1, label="gridrt cast", color="C9")
    if embree:
        u = np.array([r["e_upload_ms"] for r in rows])
        cm = np.array([r["e_commit_ms"] for r in rows])
        ce = np.array([r["e_cast_ms"] for r in rows])
        a.bar(x + 0.2, u, 0.4, label="Embree upload (embreex)", color="C7")
        a.bar(x + 0.2, cm, 0.4, bottom=u, label="Embree commit", color="C3")
        a.bar(x + 0.2, ce, 0.4, bottom=u + cm, label="Embree cast", color="C1")
    a.set_xticks(x, labels, fontsize=6)
    a.set_ylabel("ms per frame (median)")
    a.legend(fontsize=6)
    a = ax[0, 1]
    a.bar(x - 0.27, [r["o_mrays"] for r in rows], 0.27, label="gridrt cast_rays", color="C0")
    a.bar(x, [r.get("o_mrays_cgt", 0) for r in rows], 0.27, label="gridrt render (CGT)", color="C2")
    if embree:
        a.bar(x + 0.27, [r["e_mrays"] for r in rows], 0.27, label="Embree", color="C3")
    a.set_xticks(x, labels, fontsize=6)
    a.set_ylabel("static cast Mrays/s (median)")
    a.legend(fontsize=7)
    fig.suptitle(f"gridrt{' against Embree' if embree else ''}: rebuild + cast per frame, and cast throughput")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
