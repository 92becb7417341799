"""``gridrt bench trade``: what each speed-for-accuracy knob buys and costs.

For one scene and camera, every knob is varied alone from a baseline (the engine's defaults, with
the DDA traversal: see :func:`baseline`): insertion test (bbox, exact), lambda (cells per
triangle), macro-cell size, intersection test (watertight, fast Moller-Trumbore), traversal (DDA,
CGT), render resolution, precision (the engine stores triangles as float32 and computes in
float64), the CGT packets' size and shape and the precision of their triangle tests (float64,
float32; these rows render with CGT), the grid kind (uniform, two_level, auto) and a two-level
grid's top and leaf densities (each swept with the other at its default; these rows build
two-level grids). For each setting: build ms, references, render ms, and the error it costs against
independent references (:mod:`gridrt.app.bench.reference`):

* pixels whose hit triangle differs from a brute-force float64 caster, on a seeded random sample
  of pixels (brute force over a whole 1024x1024 image would take minutes); a lower resolution is
  compared pixel for pixel after nearest-neighbour upscaling;
* mean and max |dt| over the sampled pixels where both hit;
* holes per million probe rays aimed at shared vertices and edges of a closed mesh from outside.

The reference casts against the float32 values the engine stores (so each knob's own error is
isolated); the precision row instead compares the default setting with the float64 source
geometry (the mesh file's values before rounding to float32), and aims its probe rays at the
float64 source vertices.  Configurations on the Pareto front of (build + render ms, pixel error,
holes) are marked.
"""

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

import gridrt  # noqa: F401
from gridrt.config import GRID_KINDS, PACKET_PRECISIONS, TRAVERSALS, GridParams, RenderParams, _packet_shape, check_strategy
from gridrt.errors import InputError
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.grid.build import GridBuilder
from gridrt.scene import StaticMesh
from gridrt.scene.mesh import quiet_trimesh
from gridrt.threads import check_threads
from gridrt.trace.render import Renderer, cast_rays

from ..cli import option_help
from .machine import finish_machine, machine_info
from .options import check_runs, float_list, int_list
from .output import figure, grid_columns, md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import resolve_scene, scene_available, scene_camera
from .stats import pareto_front, put_stat
from .reference import HOLE_REL, brute_cast, compare_to_reference, count_holes, pixel_rays, probe_rays, sample_pixels

KNOBS = ("insert", "lambda", "macro", "intersect", "traversal", "resolution", "precision", "packet",
         "packet_precision", "grid", "top_density", "leaf_density")
#: knobs of the CGT packets: their rows render with the CGT traversal
CGT_KNOBS = ("packet", "packet_precision")
DEFAULT_PACKETS = "4,8,16,16x8,8x16"
DEFAULT_LAMBDAS = "0.5,1,2,3,4,6,8,12"
DEFAULT_MACROS = "1,2,4,8,16"
DEFAULT_RESOLUTIONS = "0.25,0.5,0.75,1"
DEFAULT_TOP_DENSITIES = "0.015625,0.03125,0.0625,0.125,0.25,0.5"
DEFAULT_LEAF_DENSITIES = "0.5,1,2,4,8"


def add_parser(bsub, common):
    t = bsub.add_parser("trade", help="speed against accuracy for every knob, against a brute-force float64 reference",
                        description=__doc__.split("\n\n")[0])
    common(t, "trade", warmup=1, scenes=False)
    t.add_argument("--scene", default=None,
                   help="image scene spec (default armadillo; icosphere:81920 when the Armadillo mesh is absent)")
    t.add_argument("--probe-mesh", default=None,
                   help="closed static mesh for the holes count (default armadillo; icosphere:20480 when the "
                        "Armadillo mesh is absent)")
    t.add_argument("--size", type=int, default=1024, help="full image edge in pixels (default 1024)")
    t.add_argument("--samples", type=int, default=4096, help="sampled pixels for the reference (default 4096)")
    t.add_argument("--probes", type=int, default=100000, help="probe rays for the holes count (default 100000)")
    t.add_argument("--threads", type=int, default=None, help=option_help("--threads", "all cores"))
    t.add_argument("--strategy", default="serial",
                   help=option_help("--strategy", "serial, as in the bbox/exact comparison of Ize et al. 2006"))
    t.add_argument("--knobs", default=None, help=f"comma-separated of {', '.join(KNOBS)} (default: all)")
    t.add_argument("--lambdas", default=DEFAULT_LAMBDAS, help=f"lambda sweep (default {DEFAULT_LAMBDAS})")
    t.add_argument("--macros", default=DEFAULT_MACROS, help=f"macro-cell sizes (default {DEFAULT_MACROS})")
    t.add_argument("--packets", default=DEFAULT_PACKETS,
                   help=f"CGT packet sizes for the packet knob, N or WxH (default {DEFAULT_PACKETS})")
    t.add_argument("--top-densities", default=DEFAULT_TOP_DENSITIES,
                   help="two-level grids' top cells per triangle for the top_density knob (leaf density at its "
                        f"default; default {DEFAULT_TOP_DENSITIES})")
    t.add_argument("--leaf-densities", default=DEFAULT_LEAF_DENSITIES,
                   help="two-level grids' leaf cells per reference of a top cell for the leaf_density knob (top "
                        f"density at its default; default {DEFAULT_LEAF_DENSITIES})")
    t.add_argument("--resolutions", default=DEFAULT_RESOLUTIONS,
                   help=f"image edges as fractions of --size (default {DEFAULT_RESOLUTIONS})")
    t.add_argument("--time", type=float, default=0.0, help="scene time in seconds (animated scenes)")
    t.add_argument("--seed", type=int, default=0, help="seed of the pixel sample and the probe rays")
    t.set_defaults(func=run_trade)


# ----------------------------------------------------------------------------------------------
# float64 source geometry (for the precision row)
# ----------------------------------------------------------------------------------------------


def source_f64(sc, tris32, origin=None):
    """(F,3,3) float64 triangles before float32 rounding, in the engine's order, or (None, why);
    in the frame of ``origin`` (world - origin, in float64) as tris32 are.

    Mesh files (.obj .ply .off .stl) are re-read with trimesh exactly as the engine reads them but
    kept in float64; icospheres are regenerated by trimesh in float64.  The result must round to
    the engine's triangles bit for bit, else it is not used.
    """
    import trimesh  # deferred: trimesh, slow to load; only the precision row re-reads a mesh in float64

    if not isinstance(sc.scene, StaticMesh) or sc.spec.subdivide or sc.spec.animate:
        return None, "precision needs a static, unsubdivided mesh file or icosphere"
    F = len(tris32)
    if sc.path is None:
        k = int(round(math.log(F / 20.0, 4))) if F > 20 else 0
        if 20 * 4**k != F:
            return None, "not an icosphere"
        with quiet_trimesh():
            ico = trimesh.creation.icosphere(subdivisions=k, radius=1.0)
        v, f = np.asarray(ico.vertices, np.float64), np.asarray(ico.faces)
    else:
        ext = sc.path.suffix.lower()
        if ext not in (".obj", ".ply", ".off", ".stl"):
            return None, f"no float64 reader for {ext} files"
        with quiet_trimesh():
            m = trimesh.load(str(sc.path), file_type=ext[1:], force="mesh", process=False)
        v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces)
    if f.shape != (F, 3):
        return None, "float64 re-read has a different triangle count"
    t64 = v[f] - (np.zeros(3) if origin is None else np.asarray(origin, np.float64))
    if not np.array_equal(t64.astype(np.float32), tris32):
        return None, "float64 re-read does not round to the engine's triangles"
    return t64, ("the file stores float32 values: float64 source = float32 values" if np.array_equal(
        t64, tris32.astype(np.float64)) else "")


# ----------------------------------------------------------------------------------------------
# the run
# ----------------------------------------------------------------------------------------------


def _default_specs(a):
    if a.quick:
        return a.scene or "icosphere:1280", a.probe_mesh or "icosphere:320"
    scene = a.scene or ("armadillo" if scene_available("armadillo") else "icosphere:81920")
    probe = a.probe_mesh or ("armadillo" if scene_available("armadillo") else "icosphere:20480")
    return scene, probe


def baseline(scene, size, strategy, threads, cam, t=0.0):
    """The FrameSpec every knob is varied from: the SceneSpec ``scene`` seen through ``cam`` at
    time ``t``, size x size, built with ``strategy`` on ``threads`` threads, everything else the
    engine's defaults (GridParams, RenderParams) except the traversal, DDA: the holes are counted
    through ``cast_rays`` with probe rays from random origins, which it traces one by one, so each
    row's holes are those of the traversal it renders with (the traversal knob's CGT row, the
    engine's default, and the packet knobs' rows, which render with CGT, show what the packets
    change).  A row's configuration is such a FrameSpec (hashable: the rows that vary one knob to
    the same setting share their measurements; configurations with equal GridParams share one
    grid)."""
    return FrameSpec(scene=scene, grid=GridParams(strategy=strategy, threads=threads),
                     render=RenderParams(size, size, threads=threads, traversal="dda"),
                     view=ViewSpec(eye=cam.eye, target=cam.target, up=cam.up, fov=cam.fov, t0=t, size=(size, size)))


def _grid(spec, **kw):
    """``spec`` with the GridParams fields ``kw`` changed."""
    return spec.replace(grid=spec.grid.replace(**kw))


def _render(spec, **kw):
    """``spec`` with the RenderParams fields ``kw`` changed."""
    return spec.replace(render=spec.render.replace(**kw))


def _describe(cfg):
    g, r = cfg.grid, cfg.render
    cgt = f" ({r.packet[0]}x{r.packet[1]} packets, {r.packet_precision} tests)" if r.traversal == "cgt" else ""
    grid = (f"{g.grid} grid (top density {g.top_density:g}, leaf density {g.leaf_density:g}), "
            if g.grid != "uniform" else "uniform grid, ")
    return (f"{grid}{g.insert}, lambda {g.density:g}, macro {g.macro}, {'watertight' if r.watertight else 'fast'}, "
            f"{r.traversal.upper()}{cgt}, {r.width}x{r.height}")


def _packet_list(text):
    try:
        return [_packet_shape(p.strip()) for p in text.split(",") if p.strip()]
    except InputError as e:
        raise InputError(f"--packets: {e}") from None


def _configs(a, knobs, d):
    """[(knob, label, FrameSpec)] varied from the baseline FrameSpec ``d`` (:func:`baseline`)."""
    size = d.size[0]
    rows = []
    lambdas = [0.5, 4.0] if a.quick and a.lambdas == DEFAULT_LAMBDAS else float_list(a.lambdas, "--lambdas")
    macros = [1, 4] if a.quick and a.macros == DEFAULT_MACROS else int_list(a.macros, "--macros")
    fracs = [0.5, 1.0] if a.quick and a.resolutions == DEFAULT_RESOLUTIONS else float_list(a.resolutions, "--resolutions")
    tops = ([0.03125, 0.25] if a.quick and a.top_densities == DEFAULT_TOP_DENSITIES
            else float_list(a.top_densities, "--top-densities"))
    leaves = ([1.0, 4.0] if a.quick and a.leaf_densities == DEFAULT_LEAF_DENSITIES
              else float_list(a.leaf_densities, "--leaf-densities"))
    g, r = d.grid, d.render
    two_level = _grid(d, grid="two_level")
    for k in knobs:
        if k == "insert":
            rows += [(k, ins, _grid(d, insert=ins)) for ins in ("bbox", "exact")]
        elif k == "lambda":
            rows += [(k, f"{lam:g}", _grid(d, density=lam)) for lam in sorted(set(lambdas) | {g.density})]
        elif k == "macro":
            for m in sorted(set(macros) | {g.macro}):
                if m > 64:
                    raise InputError(f"--macros: macro-cell size must be at most 64, got {m}")
                rows.append((k, str(m), _grid(d, macro=m)))
        elif k == "intersect":
            rows += [(k, "watertight" if wt else "fast", _render(d, watertight=wt)) for wt in (True, False)]
        elif k == "traversal":
            rows += [(k, tr, _render(d, traversal=tr)) for tr in TRAVERSALS]
        elif k == "packet":
            shapes = [(8, 8), (16, 16)] if a.quick and a.packets == DEFAULT_PACKETS else _packet_list(a.packets)
            rows += [(k, f"{w}x{h}", _render(d, traversal="cgt", packet=(w, h)))
                     for w, h in dict.fromkeys(shapes + [r.packet])]
        elif k == "packet_precision":
            rows += [(k, prec, _render(d, traversal="cgt", packet_precision=prec)) for prec in PACKET_PRECISIONS]
        elif k == "resolution":
            sizes = sorted({max(1, int(round(f * size))) for f in fracs} | {size})
            if max(sizes) > size:
                raise InputError("--resolutions: fractions must be at most 1 (the reference is at --size)")
            rows += [(k, f"{n}x{n}", d.resized(n, n)) for n in sizes]
        elif k == "precision":
            rows.append((k, "float32 storage", d))
        elif k == "grid":
            rows += [(k, kind, _grid(d, grid=kind)) for kind in GRID_KINDS]
        elif k == "top_density":
            rows += [(k, f"{t:g}", _grid(two_level, top_density=t)) for t in sorted(set(tops) | {g.top_density})]
        elif k == "leaf_density":
            rows += [(k, f"{v:g}", _grid(two_level, leaf_density=v)) for v in sorted(set(leaves) | {g.leaf_density})]
    return rows


@dataclass
class _Options:
    """The checked options of a run: knobs, image edge, timing rounds, sample and probe counts."""

    knobs: tuple
    threads: int
    size: int
    runs: int
    warmup: int
    n_samples: int
    n_probes: int


@dataclass
class _Setup:
    """The image scene (its triangles in its frame, camera, diagonal), the probe mesh and the
    references: the sampled pixels' rays and brute-force hits, the float64 source geometry's, and
    the probe rays (float32 targets, and float64 source targets where there is a source)."""

    sc: object
    tris: np.ndarray
    cam: object
    diag: float
    pm: object
    mesh: object
    probe_tris: np.ndarray
    probe_why: str
    xs: np.ndarray
    ys: np.ndarray
    ref32: tuple
    ref_ms: float
    ref64: tuple | None
    src_why: str
    probes: tuple
    probes64: tuple | None


def run_trade(a):
    o = _options(a)
    out = out_dir(a.out)
    info = machine_info([o.threads], probe=not a.quick)
    su = _setup(a, o, *_default_specs(a))
    dcfg = baseline(su.sc.spec, o.size, a.strategy, o.threads, su.cam, a.time)
    configs = _configs(a, o.knobs, dcfg)
    unique = list(dict.fromkeys(c for _, _, c in configs))
    meas, holes_cache = _measure(a, o, su, unique, dcfg)
    rows = _rows(configs, unique, meas, holes_cache, dcfg, su, o.n_samples)
    finish_machine(info)
    _write(a, o, su, rows, meas, dcfg, info, out)
    return 0


def _options(a):
    """The run's options, checked (--quick shrinks them)."""
    check_runs(a.runs, a.warmup)
    knobs = KNOBS if a.knobs is None else tuple(k.strip() for k in a.knobs.split(",") if k.strip())
    if a.knobs is None and a.quick:
        knobs = tuple(k for k in KNOBS if k != "traversal" and k not in CGT_KNOBS)
    for k in knobs:
        if k not in KNOBS:
            raise InputError(f"unknown knob {k!r}; choose from {', '.join(KNOBS)}")
    if not knobs:
        raise InputError("--knobs: need at least one knob")
    if "packet" in knobs:
        _packet_list(a.packets)  # (checked before the reference is computed)
    if "top_density" in knobs:
        float_list(a.top_densities, "--top-densities")
    if "leaf_density" in knobs:
        float_list(a.leaf_densities, "--leaf-densities")
    check_strategy(a.strategy)
    threads = check_threads(a.threads)
    size = 64 if a.quick else a.size
    if size < 2:
        raise InputError(f"--size must be at least 2, got {size}")
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    n_samples = min(256 if a.quick else a.samples, size * size)
    n_probes = 2000 if a.quick else a.probes
    if n_samples < 1 or n_probes < 8:
        raise InputError("--samples must be >= 1 and --probes >= 8")
    if not math.isfinite(a.time):
        raise InputError("--time must be finite")
    return _Options(knobs, threads, size, runs, warmup, n_samples, n_probes)


def _setup(a, o, scene_spec, probe_spec):
    """The image scene, the probe mesh and the brute-force references (see :class:`_Setup`)."""
    threads, size, n_samples, n_probes = o.threads, o.size, o.n_samples, o.n_probes
    sc = resolve_scene(scene_spec)
    origin = sc.scene.frame_origin(a.time)  # measured in the frame the pipeline renders the scene in
    tris = np.array(sc.scene.triangles_at(a.time, origin=origin))
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    cam = scene_camera(sc.scene, tris, a.time, origin=origin)
    diag = float(np.linalg.norm(hi.astype(np.float64) - lo))
    pm = resolve_scene(probe_spec)
    mesh = getattr(pm.scene, "mesh", None)
    if mesh is None or not pm.scene.static:
        raise InputError(f"--probe-mesh {probe_spec!r} must be a static closed mesh (file or icosphere)")
    p_origin = pm.scene.frame_origin(0.0)
    probe_tris = np.ascontiguousarray(mesh.triangles(p_origin))
    probe_v = (mesh.vertices64 - p_origin).astype(np.float32)  # the probe mesh in its frame
    probe_src, probe_why = source_f64(pm, probe_tris, p_origin)

    # references
    xs, ys = sample_pixels(size, size, n_samples, a.seed)
    O, D = pixel_rays(cam.eye, cam.target, cam.up, cam.fov, size, size, xs, ys)
    print(f"trade: brute-force float64 reference on {n_samples} sampled pixels x {len(tris):,} triangles...",
          file=sys.stderr)
    brute_cast(tris[:1], O[:1], D[:1], threads=threads)  # compile outside the timing
    t0 = time.perf_counter()
    ref32 = brute_cast(tris, O, D, threads=threads)
    ref_ms = (time.perf_counter() - t0) * 1e3
    src64, src_why = (None, "")
    ref64 = None
    if "precision" in o.knobs:
        src64, src_why = source_f64(sc, tris, origin)
        if src64 is not None:
            ref64 = brute_cast(src64, O, D, threads=threads)
    probes = probe_rays(probe_v, mesh.faces, n_probes, seed=a.seed)
    probes64 = None
    if probe_src is not None:
        # the same targets as the float32 probes (same seed, same topology) at the float64
        # source positions of the mesh's indexed vertices
        vsrc = probe_v.astype(np.float64)
        vsrc[mesh.faces.reshape(-1)] = probe_src.reshape(-1, 3)
        probes64 = probe_rays(vsrc, mesh.faces, n_probes, seed=a.seed)
    return _Setup(sc, tris, cam, diag, pm, mesh, probe_tris, probe_why, xs, ys, ref32, ref_ms, ref64, src_why,
                  probes, probes64)


def _measure(a, o, su, unique, dcfg):
    """Every configuration's figures: pass 1 (warm-up, errors, holes), then the timed rounds."""
    threads, size, runs, warmup = o.threads, o.size, o.runs, o.warmup
    tris, cam, xs, ys, ref32, ref64 = su.tris, su.cam, su.xs, su.ys, su.ref32, su.ref64
    po, pd, pdist = su.probes
    po64, pd64, pdist64 = su.probes64 if su.probes64 is not None else (None, None, None)
    gkeys = list(dict.fromkeys(c.grid for c in unique))  # one grid per GridParams
    builders = {gk: GridBuilder(gk) for gk in gkeys}
    renderers = {cfg: Renderer() for cfg in unique}
    bar = progress(len(unique) + runs, "bench trade", a.no_progress)
    # pass 1: warm-up, the error figures and the holes, configuration by configuration
    grids, meas, holes_cache = {}, {}, {}
    for cfg in unique:
        gk, rp = cfg.grid, cfg.render
        wt, res, trav = rp.watertight, rp.width, rp.traversal
        bar.set_postfix_str(f"{gk.insert} l={gk.density:g} m={gk.macro} {'wt' if wt else 'fast'} {res} {trav} "
                            f"{rp.packet[0]}x{rp.packet[1]} {rp.packet_precision} {gk.grid} "
                            f"t={gk.top_density:g} f={gk.leaf_density:g}")
        if gk not in grids:
            for _ in range(max(warmup, 1)):
                grids[gk] = builders[gk].build(tris)
        g = grids[gk]
        for _ in range(max(warmup, 1)):
            img = renderers[cfg].render(g, tris, cam, rp)
        rx = xs * res // size
        ry = ys * res // size
        m = dict(grid_columns(gk, g.stats), refs_per_tri=g.references / len(tris),
                 dims="x".join(str(int(x)) for x in g.spec.dims), hit_fraction=img.stats["hit_fraction"],
                 tests_per_ray=img.stats["tests_per_ray"], cells_per_ray=img.stats["cells_per_ray"])
        m["cmp32"] = compare_to_reference(img.tri[ry, rx], img.t[ry, rx], ref32[1], ref32[0], ref32[2])
        if ref64 is not None and cfg == dcfg:
            m["cmp64"] = compare_to_reference(img.tri[ry, rx], img.t[ry, rx], ref64[1], ref64[0], ref64[2])
        hk = (gk, wt)
        if trav != "dda":
            m["holes"] = None  # the probe rays (random origins) go through cast_rays one by one, not as packets
        else:
            if hk not in holes_cache:
                pg = GridBuilder(builders[gk].params).build(su.probe_tris)
                h = cast_rays(pg, su.probe_tris, po, pd, watertight=wt, threads=threads)
                holes_cache[hk] = count_holes(h.t, h.tri, pdist)
                if po64 is not None and cfg == dcfg:
                    h = cast_rays(pg, su.probe_tris, po64, pd64, watertight=wt, threads=threads)
                    holes_cache["precision"] = count_holes(h.t, h.tri, pdist64)
            m["holes"] = holes_cache[hk]
        meas[cfg] = m
        bar.update()
    # pass 2: timed rounds, every build and every render once per round, so load from other
    # processes is spread over all configurations alike
    bt = {gk: [] for gk in gkeys}
    rt = {cfg: [] for cfg in unique}
    for _ in range(runs):
        for gk in gkeys:
            grids[gk] = builders[gk].build(tris)
            bt[gk].append(grids[gk].stats["build_ms"])
        for cfg in unique:
            t0 = time.perf_counter()
            renderers[cfg].render(grids[cfg.grid], tris, cam, cfg.render)
            rt[cfg].append((time.perf_counter() - t0) * 1e3)
        bar.update()
    bar.close()
    for cfg in unique:
        put_stat(meas[cfg], "build_ms", bt[cfg.grid])
        put_stat(meas[cfg], "render_ms", rt[cfg])
    return meas, holes_cache


def _rows(configs, unique, meas, holes_cache, dcfg, su, n_samples):
    """The CSV rows, one per (knob, value), with the Pareto front over the unique configurations
    (precision is not a setting)."""
    po = su.probes[0]
    po64 = su.probes64[0] if su.probes64 is not None else None
    pts = []
    for cfg in unique:
        m = meas[cfg]
        m["total_ms"] = m["build_ms"] + m["render_ms"]
        holes = m["holes"] if m["holes"] is not None else meas.get(dcfg, {}).get("holes")
        pts.append((m["total_ms"], m["cmp32"]["differs"] / n_samples,
                    (holes or 0) / len(po) * 1e6))
    front = {unique[i] for i in pareto_front(pts)}
    rows = []
    for knob, label, cfg in configs:
        m = meas[cfg]
        g, r = cfg.grid, cfg.render
        prec = knob == "precision"
        c = m.get("cmp64") if prec else m["cmp32"]
        if prec and c is None:
            continue
        holes = holes_cache.get("precision") if prec else m["holes"]
        n_pr = len(po64) if prec and po64 is not None else len(po)
        rows.append(dict(
            knob=knob, value=label, default=int(cfg == dcfg), insert=g.insert, **{"lambda": g.density},
            macro=g.macro, intersection="watertight" if r.watertight else "fast", resolution=r.width,
            traversal=r.traversal, packet=f"{r.packet[0]}x{r.packet[1]}", packet_precision=r.packet_precision,
            grid=g.grid, grid_built=m["grid_built"], top_density=g.top_density, leaf_density=g.leaf_density,
            build_ms=m["build_ms"], build_ms_min=m["build_ms_min"], build_ms_max=m["build_ms_max"],
            references=m["references"], refs_per_tri=m["refs_per_tri"], cells=m["cells"], dims=m["dims"],
            grid_bytes=m["grid_bytes"], bytes_per_tri=m["bytes_per_tri"],
            render_ms=m["render_ms"], render_ms_min=m["render_ms_min"], render_ms_max=m["render_ms_max"],
            total_ms=m["total_ms"], tests_per_ray=m["tests_per_ray"], cells_per_ray=m["cells_per_ray"],
            samples=c["samples"], pixels_differ=c["differs"], pixel_error=c["differs"] / c["samples"], ties=c["ties"],
            both_hit=c["both_hit"], dt_mean=c["dt_mean"], dt_max=c["dt_max"], dt_rel_mean=c["dt_rel_mean"],
            dt_rel_max=c["dt_rel_max"], probe_rays=n_pr if holes is not None else "",
            holes="" if holes is None else holes, holes_per_million="" if holes is None else holes / n_pr * 1e6,
            pareto="" if prec else int(cfg in front),
        ))
    return rows


def _write(a, o, su, rows, meas, dcfg, info, out):
    """trade.csv, machine.json, the two plots and summary.md; the tables on stdout."""
    sc = su.sc
    write_csv(rows, out / "trade.csv")
    write_json(info, out / "machine.json")
    _plot_trade(rows, out / "trade.png")
    _plot_knobs(rows, out / "trade_knobs.png")
    ctx = dict(baseline=_describe(dcfg), scene=sc, tris=su.tris, size=o.size, n_samples=o.n_samples, seed=a.seed,
               ref_ms=su.ref_ms, threads=o.threads, strategy=a.strategy, runs=o.runs, warmup=o.warmup, probe=su.pm,
               n_probes=len(su.probes[0]), diag=su.diag, ref_hits=int((su.ref32[1] >= 0).sum()),
               src_why=su.src_why, probe_why=su.probe_why, has64=su.ref64 is not None, knobs=o.knobs,
               hit_fraction=meas[dcfg]["hit_fraction"] if dcfg in meas else float("nan"),
               camera="the scene's own camera" if getattr(sc.scene, "camera_at", lambda t: None)(a.time) is not None
               else "camera along the scene's thinnest axis")
    body = _summary(rows, ctx)
    write_summary(out / "summary.md", "gridrt bench trade", info,
                  [("Results", body), ("Figures", ["![pareto](trade.png)", "", "![knobs](trade_knobs.png)"])])
    for line in body:
        if line.startswith("|"):
            print(line)
    print(f"wrote {out}/trade.csv, trade.png, trade_knobs.png, summary.md")


def _g(x, digits=3):
    if x == "" or x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    return f"{x:.{digits}g}"


def _summary(rows, c):
    sc = c["scene"]
    F = len(c["tris"])
    size = c["size"]
    ray_ms = c["ref_ms"] / c["n_samples"]
    body = [
        f"Scene `{sc.label}` ({sc.scene.name}, {F:,} triangles, bounding-box diagonal {c['diag']:.4g}), "
        f"{c['camera']}, full image {size}x{size}, {100 * c['hit_fraction']:.0f}% of the pixels cover geometry.  "
        f"Build: strategy {c['strategy']}"
        f"{' (one thread)' if c['strategy'] == 'serial' else ''}; render: {c['threads']} thread(s), lambert shading.  "
        f"Times: median [min-max] of {c['runs']} runs after {c['warmup']} warm-up.",
        "",
        f"Reference: a brute-force double-sided Moller-Trumbore caster in float64 over all triangles "
        f"(`app/bench/reference.py`, independent of the engine's kernels) on a sample of {c['n_samples']} pixels drawn "
        f"uniformly without replacement from the {size}x{size} image (numpy default_rng(seed={c['seed']})); "
        f"{c['ref_hits']} of them hit the mesh.  Brute force took {c['ref_ms']:.0f} ms for the sample "
        f"({ray_ms:.2f} ms per ray, about {ray_ms * size * size / 1e3:.0f} s for a whole frame), which is why "
        "the reference is sampled.  'px differ' = sampled pixels whose hit triangle differs (hit vs miss "
        "counts; exact ties between two triangles do not) / all sampled pixels; |dt| over sampled pixels where "
        "both hit, in scene units (the engine's t buffer is float32).  Lower resolutions are compared after "
        "nearest-neighbour upscaling.",
        "",
        f"Holes: {c['n_probes']:,} probe rays from outside aimed exactly at shared vertices, edge midpoints and "
        f"random edge points of the closed mesh `{c['probe'].label}` ({c['probe'].scene.n_triangles:,} triangles), "
        "each from a direction in front of every face at its target; a hole is a ray that misses or hits farther "
        f"than its target distance x (1 + {HOLE_REL:g}).  Probe rays (random origins) go through `cast_rays` one by "
        "one, so the rows that render with CGT (traversal cgt, packet, packet_precision) have no holes figure "
        "here; tests/test_watertight.py and tests/test_soak.py probe the packets, float32 included.",
        "",
    ]
    table = []
    for r in rows:
        mark = ("**default**" if r["default"] else "") + (" front" if r["pareto"] == 1 else "")
        table.append([r["knob"], r["value"], mark.strip(), f"{r['build_ms']:.1f} [{r['build_ms_min']:.1f}-{r['build_ms_max']:.1f}]",
                      f"{r['references']:,}", f"{r['render_ms']:.1f} [{r['render_ms_min']:.1f}-{r['render_ms_max']:.1f}]",
                      f"{r['total_ms']:.1f}", f"{r['bytes_per_tri']:.1f}",
                      f"{100 * r['pixel_error']:.3f}% ({r['pixels_differ']})", r["ties"],
                      _g(r["dt_mean"]), _g(r["dt_max"]), _g(r["holes_per_million"], 4)])
    body += md_table(["knob", "value", "marks", "build ms", "references", "render ms", "build+render ms",
                      "grid bytes/tri", "px differ", "ties", "mean abs dt", "max abs dt", "holes / M rays"], table)
    body += [""]
    front = [r for r in rows if r["pareto"] == 1]
    seen = set()
    names = []
    for r in sorted(front, key=lambda r: r["total_ms"]):
        key = (r["insert"], r["lambda"], r["macro"], r["intersection"], r["resolution"], r["traversal"], r["packet"],
               r["packet_precision"], r["grid"], r["top_density"], r["leaf_density"])
        if key in seen:
            continue
        seen.add(key)
        names.append(f"{r['knob']}={r['value']} ({r['total_ms']:.0f} ms, {100 * r['pixel_error']:.2f}% px, "
                     f"{_g(r['holes_per_million'], 3)} holes/M)")
    body += ["Pareto front of (build + render ms, px differ, holes per million), costs within 3% counted as equal "
             "(timing noise); each row varies one knob from the baseline:", ""] + [f"- {n}" for n in names]
    d = next((r for r in rows if r["default"] and r["knob"] != "precision"), None)
    if d is not None:
        if d["pareto"] == 1:
            body += ["", f"The baseline ({c['baseline']}) is on the front."]
        else:
            dom = [r for r in front if r["total_ms"] <= d["total_ms"] and r["pixel_error"] <= d["pixel_error"]
                   and (r["holes_per_million"] or 0) <= (d["holes_per_million"] or 0)]
            best = min(dom, key=lambda r: r["total_ms"]) if dom else None
            body += ["", f"The baseline ({c['baseline']}) is **not** on the front"
                     + (f": {best['knob']}={best['value']} is {d['total_ms'] / best['total_ms']:.2f}x faster "
                        f"({best['total_ms']:.0f} against {d['total_ms']:.0f} ms) at no more error." if best else ".")]
    ins = {r["value"]: r for r in rows if r["knob"] == "insert"}
    if "bbox" in ins and "exact" in ins:
        b, e = ins["bbox"], ins["exact"]
        body += ["", "Our version of the Conference point of Ize et al. 2006 (bbox -> exact insertion; they measured 1.24M -> "
                 "0.83M references, render 339 -> 330 ms, serial rebuild 82 -> 245 ms on the 282k Conference):",
                 "", *md_table(["", "bbox", "exact", "change"], [
                     ["references", f"{b['references']:,}", f"{e['references']:,}",
                      f"{100 * (e['references'] / b['references'] - 1):+.1f}%"],
                     ["render ms", f"{b['render_ms']:.1f}", f"{e['render_ms']:.1f}",
                      f"{100 * (e['render_ms'] / b['render_ms'] - 1):+.1f}%"],
                     ["build ms", f"{b['build_ms']:.1f}", f"{e['build_ms']:.1f}",
                      f"{e['build_ms'] / b['build_ms']:.2f}x"],
                     ["tests per ray", f"{b['tests_per_ray']:.2f}", f"{e['tests_per_ray']:.2f}",
                      f"{100 * (e['tests_per_ray'] / b['tests_per_ray'] - 1):+.1f}%"],
                 ])]
    if "precision" in c["knobs"]:
        p = next((r for r in rows if r["knob"] == "precision"), None)
        if p is None:
            body += ["", f"Precision: not measured for this scene ({c['src_why']})."]
        else:
            body += ["", f"Precision: the default render compared with brute force over the float64 source geometry: "
                     f"{100 * p['pixel_error']:.3f}% of sampled pixels differ, max |dt| {_g(p['dt_max'])} "
                     f"(relative {_g(p['dt_rel_max'])})" + (f" ({c['src_why']})" if c["src_why"] else "")
                     + (f"; probe rays aimed at the float64 source vertices of the probe mesh: "
                        f"{_g(p['holes_per_million'], 4)} holes per million" if p["holes"] != "" else "")
                     + ".  The engine has no float64-storage "
                     "mode, so this row is not a choice and is left out of the Pareto front."]
    return body


KNOB_COLORS = {"insert": "C0", "lambda": "C1", "macro": "C2", "intersect": "C3", "traversal": "C4",
               "resolution": "C5", "precision": "C7", "packet": "C8", "packet_precision": "C9", "grid": "C6",
               "top_density": "navy", "leaf_density": "darkolivegreen"}


def _plot_trade(rows, path):
    from matplotlib.lines import Line2D  # deferred: matplotlib, slow to load; plots only

    pts = [r for r in rows if r["knob"] != "precision"]
    fig, ax = figure(1, 2, w=6.0, h=4.4)
    for k, (key, ylab) in enumerate((("pixel_error", "fraction of sampled pixels that differ"),
                                     ("holes_per_million", "holes per million probe rays"))):
        a = ax[0, k]
        done_default = False
        for r in pts:
            y = r[key]
            if y == "":
                continue
            if r["default"]:
                if done_default:
                    continue
                done_default = True
                a.scatter(r["total_ms"], y, color="k", s=110, marker="*", zorder=4)
                a.annotate("baseline", (r["total_ms"], y), fontsize=7, xytext=(4, -10), textcoords="offset points")
                continue
            a.scatter(r["total_ms"], y, color=KNOB_COLORS[r["knob"]], s=26,
                      edgecolors="k" if r["pareto"] == 1 else "none", linewidths=1.2, zorder=3)
            a.annotate(r["value"], (r["total_ms"], y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        fr = sorted((r["total_ms"], r[key]) for r in pts if r["pareto"] == 1 and r[key] != "")
        if fr:
            best, xs, ys = float("inf"), [], []
            for x, y in fr:
                if y < best:
                    best = y
                    xs.append(x)
                    ys.append(y)
            a.step(xs, ys, where="post", color="k", linewidth=0.8, alpha=0.5)
        a.set_xscale("log")
        a.set_yscale("symlog", linthresh=1e-4 if key == "pixel_error" else 1.0)
        a.set_ylim(bottom=0)
        a.set_xlabel("build + render ms (median)")
        a.set_ylabel(ylab)
        a.grid(True, alpha=0.3)
    knobs = list(dict.fromkeys(r["knob"] for r in pts))
    handles = [Line2D([], [], marker="o", linestyle="", color=KNOB_COLORS[k], label=k) for k in knobs]
    handles += [Line2D([], [], marker="*", linestyle="", color="k", markersize=10, label="baseline"),
                Line2D([], [], marker="o", linestyle="", color="w", markeredgecolor="k", label="Pareto front")]
    ax[0, 0].legend(handles=handles, fontsize=7)
    fig.suptitle("speed against accuracy: one knob at a time from the baseline")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _plot_knobs(rows, path):
    knobs = [k for k in dict.fromkeys(r["knob"] for r in rows) if k != "precision"]
    if not knobs:
        knobs = ["precision"]
    ncols = min(3, len(knobs))
    nrows = math.ceil(len(knobs) / ncols)
    fig, ax = figure(nrows, ncols, w=4.6, h=3.4)
    for n, k in enumerate(knobs):
        a = ax[n // ncols, n % ncols]
        rs = [r for r in rows if r["knob"] == k]
        x = np.arange(len(rs))
        a.bar(x - 0.2, [r["build_ms"] for r in rs], 0.4, label="build ms")
        a.bar(x + 0.2, [r["render_ms"] for r in rs], 0.4, label="render ms")
        a.set_xticks(x, [r["value"] for r in rs], fontsize=7)
        a.set_title(k, fontsize=9)
        a.set_yscale("log")
        for i, r in enumerate(rs):
            a.annotate(f"{100 * r['pixel_error']:.2g}%", (i, max(r["build_ms"], r["render_ms"])), fontsize=6,
                       ha="center", xytext=(0, 2), textcoords="offset points")
        if n == 0:
            a.legend(fontsize=7)
    for n in range(len(knobs), nrows * ncols):
        ax[n // ncols, n % ncols].set_visible(False)
    fig.suptitle("per knob: median build and render ms (labels: sampled pixels that differ)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
