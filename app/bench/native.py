"""``gridrt bench native``: gridrt against native Embree 3 (C++) on the same mesh, the same rays and the
same animated frames, in one run.

Native Embree is the C++ harness of the development machine's shared tools (``embree_bench``: Embree
3.13, AVX-512 BVH8, ``rtcIntersect1``, native 16-ray packets and ray streams, refit and rebuild of a
deforming mesh; its build.sh compiles it).  For each scene this benchmark writes a folder in the
harness's format (:func:`export_folder`: the mesh, its animated frames as vertex sets, the view's
camera rays and as many random rays, all float32, in the frame the pipeline uses), runs the harness on
it at every thread count (the process pinned to that many CPUs, the harness's child included), and
times gridrt on the very same arrays in the same process:

* arbitrary rays: ``RayCaster.cast`` (nearest hit, watertight) on the random rays, against native
  ``rtcIntersect1`` (and its packets and streams) and, where installed, the Python wrapper embreex
  (robust scene flag);
* camera rays passed as arrays: ``RayCaster.cast`` on the view's rays in row order;
* camera rays: gridrt's CGT render of the same camera (which also shades and writes the image; the
  harness's figures are hits only), against native Embree's best mode;
* dynamic frames: the frames' vertex sets one after another, gridrt rebuilding its grid from scratch
  and rendering with CGT (build + render), and ``RayCaster.update`` + ``cast`` of the camera rays,
  against the harness's refit frame and rebuild frame (update + 16-ray packets);
* hit agreement: gridrt's hits against the harness's (camera rays against its 16-ray packets, random
  rays against ``rtcIntersect1``), every disagreeing ray (at most 256) checked against the float64
  brute force.

The mesh goes to the harness with its vertices unshared (three per triangle, the triangles gridrt
traces, bit for bit), so both trace the same triangles in the same order and ids.
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import gridrt  # noqa: F401
from gridrt.api import RayCaster
from gridrt.config import RenderParams
from gridrt.errors import InputError
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.grid.build import GridBuilder
from gridrt.trace.render import Renderer

from ..cli import option_help

from .affinity import Affinity
from .harness import NATIVE_WARMUP, add_export_args, export_arg, export_folder, folder_name
from .machine import finish_machine, machine_info
from .options import add_dt_arg, check_frame_args, thread_list
from .output import figure, md_table, out_dir, progress, write_csv, write_json, write_summary
from .peers import CHECK_MAX, agreement, disagreeing, peer_rays, peer_specs, right_against
from .reference import brute_cast
from .scenes import resolve_scene, scene_list
from .sides import EmbreeSide, MissingPeer
from .stats import put_stat, timings

#: the harness's sources beside the repository (the development machine's shared tools)
HARNESS_DIR = Path(__file__).resolve().parents[3] / "shared" / "tools" / "embree-native"
#: where the harness's build.sh puts the binary
DEFAULT_BIN = Path(os.environ.get("TMPDIR") or "/tmp") / "embree-native" / "embree_bench"
#: meshes filling the view from 20k to 1.3M triangles, and the marbles (640k moving triangles)
NATIVE_SCENES = ["icosphere:20480:twist", "lucy:twist", "icosphere:1310720:twist", "marbles:640000"]
NATIVE_FALLBACK = ["icosphere:20480:twist", "icosphere:81920:twist", "icosphere:1310720:twist", "marbles:640000"]
#: the harness's cast modes
MODES = ("1", "p16", "1M")


def add_parser(bsub, common):
    p = bsub.add_parser("native", help="the same mesh, rays and frames through native Embree 3 (C++) side by side",
                        description=__doc__.split("\n\n")[0])
    common(p, "native", runs=5, warmup=1, scenes=(NATIVE_SCENES, NATIVE_FALLBACK))
    p.add_argument("--threads", default=None, help=option_help("--threads", "1 and all cores", several=True))
    p.add_argument("--size", type=int, default=1024,
                   help="camera image edge, a multiple of 8: size x size camera rays and as many random rays "
                        "(default 1024)")
    p.add_argument("--view", default="fill", choices=("frame", "fill"),
                   help="the camera: the scene's own (frame), or moved in until 90%% of the pixels hit (fill: a "
                        "full-frame mesh) (default fill)")
    p.add_argument("--strategy", default="auto", help=option_help("--strategy"))
    add_dt_arg(p)
    p.add_argument("--native-bin", default=str(DEFAULT_BIN),
                   help=f"the harness's binary (default {DEFAULT_BIN}, where its build.sh writes it)")
    add_export_args(p, "a temporary folder, removed at the end")
    p.set_defaults(func=run_native)


def build_hint():
    where = HARNESS_DIR / "build.sh"
    if where.is_file():
        return f"build it with `bash {where}` (or pass --native-bin)"
    return (f"the harness is not beside this clone ({HARNESS_DIR} is absent): build its embree_bench and pass "
            "--native-bin, or write the folders with --export DIR --export-only")


def check_binary(path):
    p = Path(path)
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise InputError(f"no native Embree harness at {p}: {build_hint()}")
    return p


def run_harness(binary, args):
    """The harness's RESULT lines (dicts) of one call; a clear error when it fails."""
    p = subprocess.run([str(binary), *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise InputError(f"the native Embree harness failed (exit {p.returncode}): {last}")
    return [json.loads(line[7:]) for line in p.stdout.splitlines() if line.startswith("RESULT ")]


def native_figures(binary, folder, T, runs, timed, hits=None):
    """Every harness measurement of one folder at T threads: static builds and casts (``runs`` reps),
    the refit and rebuild frames (``timed`` of them after the warm-up), as a flat dict of ms (and
    the hit fractions)."""
    extra = []
    if hits:
        Path(hits).mkdir(parents=True, exist_ok=True)
        extra = ["--hits", hits]
    res = run_harness(binary, ["static", folder, T, runs, *extra])
    for update in ("refit", "rebuild"):
        res += run_harness(binary, ["dynamic", folder, T, timed, update, "p16"])
    out = {}
    for r in res:
        if r["kind"] == "build":
            out[f"n_build_{r['build']}_ms"] = 1e3 * r["build_s"]
        elif r["kind"] == "cast":
            out[f"n_{r['rays']}_{r['mode']}_ms"] = 1e3 * r["cast_s"]
            if r["mode"] == "p16":
                out[f"n_{r['rays']}_hit"] = r.get("hit", float("nan"))
        elif r["kind"] == "dynamic":
            for k in ("frame", "update", "cast"):
                out[f"n_{r['update']}_{k}_ms"] = 1e3 * r[f"{k}_s"]
    return out


#: barycentric distance from a triangle's edge within which float32 rounding may decide which of two
#: neighbours a ray hits (the watertight test runs on float32 vertices in ray space: its edge functions
#: err by about 6e-8 of the vertices' distance from the ray's origin, over the triangle's size)
EDGE_TOL = 1e-4


def _bary_min(tris, o, d, f):
    """min(u, v, 1 - u - v) of each ray's crossing of the plane of triangle f (float64; -inf where
    f < 0 or the ray is parallel to the plane): >= 0 inside, how far outside otherwise."""
    out = np.full(len(o), -np.inf)
    k = np.flatnonzero(f >= 0)
    if not len(k):
        return out
    T = tris[f[k]]
    v0, e1, e2 = T[:, 0], T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    p = np.cross(d[k], e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o[k] - v0
        u = np.einsum("ij,ij->i", s, p) * inv
        v = np.einsum("ij,ij->i", d[k], np.cross(s, e1)) * inv
        m = np.minimum(np.minimum(u, v), 1.0 - u - v)
    out[k] = np.where(np.isfinite(m), m, -np.inf)
    return out


def _judge(tris, o, d, idx, ours, theirs, threads):
    """Of the disagreeing rays idx (the first CHECK_MAX), how many each side got right against the
    float64 brute force (the same triangle, a tie within rounding, or both miss), and how many
    more it got within float32 rounding of an edge: the brute force's triangle is hit within
    EDGE_TOL of its edge and the side's triangle (or the side's miss) lies within EDGE_TOL on the
    other side of it.  Returns (checked, ours right, ours at an edge, theirs right, theirs at an
    edge)."""
    idx = idx[:CHECK_MAX]
    if not len(idx):
        return 0, 0, 0, 0, 0
    o, d = o[idx], d[idx]
    rt, rf, rt2 = brute_cast(tris, o, d, threads=threads)
    scale = np.maximum(np.abs(rt), 1e-30)
    ref_edge = _bary_min(tris, o, d, rf)

    def judged(t, f):
        t, f = t[idx], f[idx]
        right = right_against(t, f, rt, rf, rt2)
        with np.errstate(invalid="ignore"):
            near_t = (f < 0) | (rf < 0) | (np.abs(t - rt) <= 1e-5 * scale)
        side_edge = _bary_min(tris, o, d, f)
        ref_ok = (rf < 0) | (ref_edge <= EDGE_TOL)
        side_ok = (f < 0) | (side_edge >= -EDGE_TOL)
        edge = ~right & ref_ok & side_ok & near_t
        return int(right.sum()), int(edge.sum())

    ours_right, ours_edge = judged(*ours)
    theirs_right, theirs_edge = judged(*theirs)
    return len(idx), ours_right, ours_edge, theirs_right, theirs_edge


def compare_hits(row, key, tris, o32, d32, ours, hdir, name, threads):
    """Agreement of gridrt's hits ``ours`` (t, tri) with the harness's saved hits ``name`` into row."""
    ft = np.load(Path(hdir) / f"{name}_tri.npy").astype(np.int64)
    tt = np.load(Path(hdir) / f"{name}_t.npy").astype(np.float64)
    t_o, f_o = np.asarray(ours[0], np.float64), np.asarray(ours[1], np.int64)
    ag = agreement(t_o, f_o, tt, ft)
    bad = disagreeing(t_o, f_o, tt, ft)
    judged = _judge(np.asarray(tris, np.float64), o32.astype(np.float64), d32.astype(np.float64), bad,
                    (t_o, f_o), (tt, ft), threads)
    row.update({f"{key}_agree": (ag["same"] + ag["both_miss"]) / len(f_o), f"{key}_disagree": len(bad)})
    for name, v in zip(("checked", "ours_right", "ours_edge", "native_right", "native_edge"), judged):
        row[f"{key}_{name}"] = v


def _time(row, key, fn, runs, warmup):
    """row[key] (with _min and _max): ms of ``runs`` calls of fn after ``warmup`` untimed ones."""
    row[key], row[key + "_min"], row[key + "_max"] = timings(fn, runs, warmup)


def measure_gridrt(row, spec, frames, o32, d32, ro32, rd32, T, runs, warmup, emb):
    """gridrt's figures on the folder's arrays at T threads into row; returns its static hits
    ((t, tri) of the camera rays, of the random rays) on frame 0."""
    F = frames.shape[1]
    V0 = frames[0].reshape(3 * F, 3)
    faces = np.arange(3 * F, dtype=np.int64).reshape(F, 3)
    gp = spec.grid
    caster = RayCaster(V0, faces, gp)
    hits = {}

    def cast(name, o, d):
        def go():
            h = caster.cast(o, d, threads=T)
            hits[name] = (h.t, h.tri)
        _time(row, f"o_cast_{name}_ms", go, runs, warmup)

    cast("random", ro32, rd32)
    cast("camera", o32, d32)
    if emb is not None:
        emb.build(frames[0])
        with ThreadPoolExecutor(T) as pool:
            for name, o, d in (("random", ro32, rd32), ("camera", o32, d32)):
                _time(row, f"e_cast_{name}_ms", lambda: emb.cast(pool, o, d, T), runs, warmup)
    builder, renderer = GridBuilder(gp), Renderer()
    cam, rp = spec.camera(), spec.render
    g0 = builder.build(frames[0])
    _time(row, "o_cgt_ms", lambda: renderer.render(g0, frames[0], cam, rp), runs, warmup)
    build, render, frame, api = [], [], [], []
    for k, tris in enumerate(frames):  # the harness's frames: the first NATIVE_WARMUP warm up
        t0 = time.perf_counter()
        g = builder.build(tris)
        t1 = time.perf_counter()
        renderer.render(g, tris, cam, rp)
        t2 = time.perf_counter()
        caster.update(tris.reshape(3 * F, 3))
        caster.cast(o32, d32, threads=T)
        t3 = time.perf_counter()
        if k >= NATIVE_WARMUP:
            build.append((t1 - t0) * 1e3)
            render.append((t2 - t1) * 1e3)
            frame.append((t2 - t0) * 1e3)
            api.append((t3 - t2) * 1e3)
    for key, v in (("o_build_ms", build), ("o_render_ms", render), ("o_frame_ms", frame), ("o_frame_api_ms", api)):
        put_stat(row, key, v)
    return hits


def run_native(a):
    check_frame_args(a)
    if a.size % 8:
        raise InputError(f"--size must be a multiple of 8 (the harness casts 8x8 tiles), got {a.size}")
    export = export_arg(a)
    binary = None if a.export_only else check_binary(a.native_bin)
    size = 64 if a.quick else a.size
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    nframes = NATIVE_WARMUP + runs
    specs, note = scene_list(a.scenes, NATIVE_SCENES, NATIVE_FALLBACK, quick=["icosphere:1280:twist"] if a.quick else None)
    threads = thread_list(a.threads)
    if note:
        print(f"note: {note}", file=sys.stderr)
    emb = None
    if not a.export_only:
        try:
            emb = EmbreeSide(robust=True)
        except MissingPeer as e:
            print(f"note: embreex not measured: {e}", file=sys.stderr)
    out = None if a.export_only else out_dir(a.out)
    info = machine_info(threads, probe=not a.quick)
    if binary is not None:
        info["native"] = " ".join(run_harness_info(binary))
    rows = []
    bar = progress(len(specs) * (1 + (0 if a.export_only else len(threads))), "bench native", a.no_progress)
    with tempfile.TemporaryDirectory(prefix="gridrt_native_") as tmp:
        root = export if export is not None else Path(tmp)
        for spec_text in specs:
            sc = resolve_scene(spec_text)
            origin, cam, o32, d32, _, _ = peer_rays(sc, size, a.view)
            _, _, ro32, rd32, _, _ = peer_rays(sc, size, "random")
            # (a copy of each frame: triangles_at may hand back the same buffer at every call)
            frames = np.stack([np.array(sc.scene.triangles_at(i * a.dt, origin=origin), np.float32)
                               for i in range(nframes)])
            folder = export_folder(root / folder_name(sc.label), sc.label, frames, cam, size, o32, d32, ro32, rd32,
                                   a.dt)
            bar.update()
            if a.export_only:
                print(f"{folder}: {sc.label}, {frames.shape[1]:,} triangles, {nframes} frames")
                continue
            base = FrameSpec(render=RenderParams(traversal="cgt"), view=ViewSpec(dt=a.dt)).resized(size, size)
            for k, spec in enumerate(peer_specs(base, sc.spec, cam, threads, ["uniform"], a.strategy)):
                T = spec.render.threads
                bar.set_postfix_str(f"{sc.label} T={T}")
                row = dict(scene=sc.label, view=a.view, triangles=int(frames.shape[1]), threads=T,
                           strategy=spec.grid.strategy, size=size, camera_rays=len(o32), random_rays=len(ro32),
                           frames=runs)
                hdir = root / folder_name(sc.label) / "hits" if k == 0 else None
                with Affinity(T) as aff:
                    row["pinned"] = aff.applied
                    row.update(native_figures(binary, folder, T, runs, runs, hdir))
                    hits = measure_gridrt(row, spec, frames, o32, d32, ro32, rd32, T, runs, warmup, emb)
                row["o_hit_camera"] = float((hits["camera"][1] >= 0).mean())
                row["o_hit_random"] = float((hits["random"][1] >= 0).mean())
                if hdir is not None:
                    compare_hits(row, "camera", frames[0], o32, d32, hits["camera"], hdir, "primary_p16", T)
                    compare_hits(row, "random", frames[0], ro32, rd32, hits["random"], hdir, "incoherent_1", T)
                _derive(row)
                rows.append(row)
                bar.update()
    bar.close()
    if a.export_only:
        return 0
    info = finish_machine(info)
    write_csv(rows, out / "native.csv")
    write_json(info, out / "machine.json")
    write_summary(out / "summary.md", "gridrt against native Embree", info, _summary(rows, runs, warmup, emb))
    _plot(rows, out / "native.png")
    for r in rows:
        print(f"{r['scene']} T={r['threads']}: random {r['o_mrays_random']:.2f} against native {r['n_mrays_random']:.2f} "
              f"Mrays/s ({r['random_over_native']:.2f}x); CGT {r['o_mrays_cgt']:.2f} against {r['n_mrays_camera']:.2f} "
              f"({r['cgt_over_native']:.2f}x); frame {r['o_frame_ms']:.1f} against refit {r['n_refit_frame_ms']:.1f} ms")
    print(f"wrote {out}/native.csv, native.png, summary.md, machine.json")
    return 0


def run_harness_info(binary):
    """Embree's version and the CPU's ISA, from the harness's info mode."""
    p = subprocess.run([str(binary), "info", "1"], capture_output=True, text=True)
    lines = [line.strip() for line in p.stdout.splitlines() if line.strip().startswith(("Embree", "ISA"))]
    return lines[:2] or ["(the harness printed no version)"]


def _derive(row):
    """Mrays/s and the ratios (above 1: gridrt is faster) of one row."""
    mr = lambda n, ms: n / ms / 1e3
    row["o_mrays_random"] = mr(row["random_rays"], row["o_cast_random_ms"])
    row["o_mrays_camera"] = mr(row["camera_rays"], row["o_cast_camera_ms"])
    row["o_mrays_cgt"] = mr(row["camera_rays"], row["o_cgt_ms"])
    for rays, key in (("incoherent", "random"), ("primary", "camera")):
        for m in MODES:
            row[f"n_mrays_{key}_{m}"] = mr(row[f"{key}_rays"], row[f"n_{rays}_{m}_ms"])
    row["n_mrays_random"] = row["n_mrays_random_1"]
    row["n_mrays_camera"] = max(row[f"n_mrays_camera_{m}"] for m in MODES)
    row["random_over_native"] = row["o_mrays_random"] / row["n_mrays_random"]
    row["camera_cast_over_native"] = row["o_mrays_camera"] / row["n_mrays_camera"]
    row["cgt_over_native"] = row["o_mrays_cgt"] / row["n_mrays_camera"]
    row["refit_over_frame"] = row["n_refit_frame_ms"] / row["o_frame_ms"]
    row["rebuild_over_frame"] = row["n_rebuild_frame_ms"] / row["o_frame_ms"]
    if "e_cast_random_ms" in row:
        row["e_mrays_random"] = mr(row["random_rays"], row["e_cast_random_ms"])
        row["e_mrays_camera"] = mr(row["camera_rays"], row["e_cast_camera_ms"])
        row["random_over_embreex"] = row["o_mrays_random"] / row["e_mrays_random"]
        row["camera_cast_over_embreex"] = row["o_mrays_camera"] / row["e_mrays_camera"]


def _summary(rows, runs, warmup, emb):
    f2 = lambda x: f"{x:.2f}"
    has_e = emb is not None
    r0 = rows[0]
    how = (f"{r0['camera_rays']:,} camera rays ({r0['size']}x{r0['size']}, view {r0['view']}) and as many random rays "
           "(origins uniform in the scene's bounds, directions uniform on the sphere), float32, the same arrays for "
           f"every tracer; gridrt: medians of {runs} runs after {warmup} warm-up; native: the harness's medians of "
           f"{runs} reps after its own warm-up; dynamic frames: {runs} timed after {NATIVE_WARMUP}.  Mrays/s; ratios "
           "above 1: gridrt is faster.")
    arb = []
    for r in rows:
        cells = [r["scene"], f"{r['triangles']:,}", r["threads"], f2(r["o_hit_random"]), f2(r["o_mrays_random"]),
                 *(f2(r[f"n_mrays_random_{m}"]) for m in MODES)]
        if has_e:
            cells.append(f2(r["e_mrays_random"]))
        cells.append(f2(r["random_over_native"]))
        if has_e:
            cells.append(f2(r["random_over_embreex"]))
        arb.append(cells)
    arb_head = ["scene", "triangles", "threads", "hit", "gridrt RayCaster.cast", "native rtcIntersect1", "native p16",
                "native rtcIntersect1M"] + (["embreex (robust)"] if has_e else []) + \
               ["cast / native rtcIntersect1"] + (["cast / embreex"] if has_e else [])
    cam = []
    for r in rows:
        cells = [r["scene"], r["threads"], f2(r["o_hit_camera"]), f2(r["o_mrays_camera"]), f2(r["o_mrays_cgt"]),
                 *(f2(r[f"n_mrays_camera_{m}"]) for m in MODES)]
        if has_e:
            cells.append(f2(r["e_mrays_camera"]))
        cells += [f2(r["camera_cast_over_native"]), f2(r["cgt_over_native"])]
        cam.append(cells)
    cam_head = ["scene", "threads", "hit", "gridrt RayCaster.cast", "gridrt CGT render", "native rtcIntersect1",
                "native p16", "native rtcIntersect1M"] + (["embreex (robust)"] if has_e else []) + \
               ["cast / native best", "CGT / native best"]
    dyn = [[r["scene"], r["threads"], f"{r['o_build_ms']:.1f} + {r['o_render_ms']:.1f} = {r['o_frame_ms']:.1f}",
            f"{r['o_frame_api_ms']:.1f}",
            f"{r['n_refit_update_ms']:.1f} + {r['n_refit_cast_ms']:.1f} = {r['n_refit_frame_ms']:.1f}",
            f"{r['n_rebuild_update_ms']:.1f} + {r['n_rebuild_cast_ms']:.1f} = {r['n_rebuild_frame_ms']:.1f}",
            f2(r["refit_over_frame"]), f2(r["rebuild_over_frame"])] for r in rows]
    dyn_head = ["scene", "threads", "gridrt build + CGT render ms", "gridrt RayCaster.update + cast ms",
                "native refit + p16 ms", "native rebuild + p16 ms", "native refit / gridrt", "native rebuild / gridrt"]
    agree = []
    for r in rows:
        if "camera_agree" not in r:
            continue
        for key, name in (("camera", "camera rays / native p16"), ("random", "random rays / native rtcIntersect1")):
            agree.append([r["scene"], name, f"{100 * r[f'{key}_agree']:.3f}%", r[f"{key}_disagree"],
                          r[f"{key}_checked"], r[f"{key}_ours_right"], r[f"{key}_ours_edge"],
                          r[f"{key}_native_right"], r[f"{key}_native_edge"]])
    agree_head = ["scene", "rays", "same hit", "disagree", "checked (float64 brute force)", "gridrt right",
                  "gridrt at an edge", "native right", "native at an edge"]
    return [("Arbitrary rays", [how, "", *md_table(arb_head, arb)]),
            ("Camera rays", ["gridrt's CGT render also shades and writes the image; the harness's casts return hits "
                             "only.  Native best: the fastest of its three modes.", "", *md_table(cam_head, cam)]),
            ("Dynamic frames", ["Per frame, the next vertex set: gridrt rebuilds its grid from scratch and renders "
                                "with CGT (or updates a RayCaster and casts the camera rays as arrays); native Embree "
                                "refits (or rebuilds, quality LOW) its BVH and casts 16-ray packets.  ms, medians; "
                                "above 1: gridrt's frame is the faster.", "", *md_table(dyn_head, dyn)]),
            ("Hit agreement", ["At the first thread count: same triangle and t within 1e-4 relative, or both miss; "
                               "disagreeing rays (at most 256) checked against the float64 brute force (right: the "
                               "same triangle, or a tie within rounding; at an edge: not right, but the brute "
                               f"force's hit lies within {EDGE_TOL:g} (barycentric) of its triangle's edge and the "
                               f"side's triangle, or its miss, within {EDGE_TOL:g} beyond it: float32 rounding "
                               "decides such rays).", "", *md_table(agree_head, agree)])]


def _plot(rows, path):
    fig, axes = figure(1, 3, w=4.5, h=4.0)
    axes = axes[0]
    labels = [f"{r['scene']}\nT={r['threads']}" for r in rows]
    x = np.arange(len(rows))
    panels = (("random rays, Mrays/s", (("gridrt cast", "o_mrays_random"), ("native rtcIntersect1", "n_mrays_random"),
                                        ("embreex", "e_mrays_random"))),
              ("camera rays, Mrays/s", (("gridrt CGT", "o_mrays_cgt"), ("gridrt cast", "o_mrays_camera"),
                                        ("native best", "n_mrays_camera"))),
              ("dynamic frame, ms", (("gridrt build + CGT", "o_frame_ms"), ("native refit", "n_refit_frame_ms"),
                                     ("native rebuild", "n_rebuild_frame_ms"))))
    for ax, (title, series) in zip(axes, panels):
        series = [(n, k) for n, k in series if k in rows[0]]
        w = 0.8 / len(series)
        for i, (name, key) in enumerate(series):
            ax.bar(x + (i - (len(series) - 1) / 2) * w, [r[key] for r in rows], w, label=name)
        ax.set_title(title)
        ax.set_xticks(x)
        ax.set_xticklabels(labels)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path)
