"""Primary-ray rendering and batch ray casting over a built grid, in parallel over tiles.

Shading (all colours linear in [0, 1], stored as ``uint8(round(255 * c))``, alpha 255):

* background (miss):   BACKGROUND = (0.12, 0.13, 0.16)
* ``lambert``:         ALBEDO * (AMBIENT + (1 - AMBIENT) * s), where s = |n . d| (headlight)
                       without shadows; with shadows s = max(0, n_f . l) * visible, n_f the unit
                       geometric normal turned towards the viewer, l the unit vector to the light,
                       visible = 0 when a shadow ray from p + n_f * 1e-6 * diag to the light hits
                       anything, else 1 (a light behind the surface gives s = 0); diag is the
                       length of the diagonal of the triangles' bounding box (unpadded).
* ``normal``:          (n_f + 1) / 2
* ``cost``:            heat map of h = min(1, tests / 64) (triangle tests of the primary ray),
                       blue (h = 0) -> green (0.5) -> red (1); also shown on background pixels.
                       With ``traversal="cgt"`` a test is one of the packet's triangle tests
                       made while the ray was active (gridrt.trace.cgt), so this image differs.

Traversal (RenderParams.traversal): ``dda`` traces one ray at a time (dda_render, threads
sharing the kernel dda_tiles); ``cgt`` traces 8x8-pixel packets and their shadow rays with
coherent grid traversal (gridrt.trace.cgt.cgt_render, threads sharing the kernel _render_tiles):
the same t, triangle and colour buffers (both give a tie, two triangles hit at exactly the same t,
to the lower triangle index).  Each is one nogil kernel that the threads of
gridrt.threads.on_threads call together, taking runs of tiles from one counter: one compile
serves every thread count, and the first frame renders on every thread.

The unit geometric normal is normalize((v1 - v0) x (v2 - v0)).
"""

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..arrays import as_origin, check_ray_values, check_rays
from ..compiles import inner
from ..config import DEFAULT_MAX_BYTES, PACKET_PRECISIONS, RenderParams, _positive_int
from ..errors import InputError
from ..grid.atomics import atomic_add
from ..grid.layout import Grid
from ..memory import check_fits
from ..stats import RenderStats
from ..threads import check_threads, launch_guard, on_threads, use_threads
from ..scene.surface import Surface, as_lights
from .batch import MAX_CELLS, SHADOW_MAX_CELLS, SHADOW_SORTED_MAX_CELLS, cast_grouped, odd_directions, tile_order
from .traverse import SCRATCH, near_all, trace_grids
from ..camera import Camera, pixel_dir
from .cgt.frame import cgt_render, tile_runs
from .grids import grid_arrays, grid_tuple
from .lightmap import LightMaps, clear_lit
from .material import (add_light, compose, draw_shift, drawn_segments, light_segments, live_segments, mark_blocked,
                       near_boxes, shade, surface_arrays)
from .records import (Buffers, HitPoints, ShadowBuffers, ShadowRays, ShadowSegments, make_draws, make_packets,
                      make_shading, make_view)
from .shade import (  # noqa: F401  (the shading constants stay importable from here)
    AMBIENT, ALBEDO, BACKGROUND, COST_SCALE, cost_rgb, facing_normal, lambert_rgb, normal_rgb, put_pixel, scene_id,
    shadow_ray,
)

#: shadow-ray origins move off the surface by this fraction of the scene's bounding-box diagonal
SHADOW_OFFSET = 1e-6
#: the render kernels' shading modes; "material" colours no hit (its pass does, after the trace)
SHADING_CODES = {"lambert": 0, "normal": 1, "cost": 2, "material": 3}


@inner(cache=True)
def _render_tile(grids, view, looks, light, ti, out, mb):
    """Tile ti (row-major) of dda_tiles, with the mailbox mb."""
    basis, W, H, tile = view.basis, view.W, view.H, view.tile
    mode, shadows, off, watertight = looks.mode, looks.shadows, looks.off, looks.watertight
    img, tbuf, idbuf, costbuf, cellbuf = out.img, out.t, out.tri, out.cost, out.cells
    ntx = (W + tile - 1) // tile
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    tx0 = (ti % ntx) * tile
    ty0 = (ti // ntx) * tile
    for y in range(ty0, min(ty0 + tile, H)):
        for x in range(tx0, min(tx0 + tile, W)):
            dx, dy, dz = pixel_dir(basis, W, H, x, y)
            which, f, t, u, v, nc, nt = trace_grids(grids, (ex, ey, ez), (dx, dy, dz), 0.0, np.inf, watertight, False, mb)
            tbuf[y, x] = np.float32(t)
            idbuf[y, x] = scene_id(grids, which, f)
            costbuf[y, x] = nt
            cellbuf[y, x] = nc
            r, g, b = BACKGROUND[0], BACKGROUND[1], BACKGROUND[2]
            if mode == 2:
                r, g, b = cost_rgb(nt)
            elif f >= 0 and mode != 3:
                nx, ny, nz, dn = facing_normal(grids[which].tris, f, dx, dy, dz)
                if mode == 1:
                    r, g, b = normal_rgb(nx, ny, nz)
                else:
                    if not shadows:
                        s = -dn
                    else:
                        need, sox, soy, soz, lx, ly, lz, ld, s = shadow_ray(
                            (ex, ey, ez), t, (dx, dy, dz), (nx, ny, nz), light, off)
                        if need:
                            sw, sf, st, su, sv, snc, snt = trace_grids(
                                grids, (sox, soy, soz), (lx, ly, lz), 0.0, ld, watertight, True, mb)
                            if sf >= 0:
                                s = 0.0
                    r, g, b = lambert_rgb(s)
            put_pixel(img, y, x, r, g, b)


@njit(cache=True, nogil=True)
def dda_tiles(grids, view, looks, light, runs, out):
    """Render tiles of the view's W x H pixels (:class:`gridrt.trace.records.View`) into the buffers
    out (:class:`gridrt.trace.records.Buffers`): img (H,W,4) uint8, t (H,W) float32, tri (H,W)
    int32, cost (H,W) int32 (triangle tests) and cells (H,W) int32 (cells visited), one ray at a
    time: runs of ``per`` consecutive tiles (row-major) taken from the counter nxt, runs = (nxt
    (1,) int64, per), until none is left, so that calls on several threads share one frame
    (:func:`dda_render`).

    grids: a tuple of GridArrays (gridrt.trace.grids), traversed together (one grid, or a scene
    split into static and moving parts); tri holds the scene ids of the hit triangles (through
    each grid's ids map where it has one).  looks: :class:`gridrt.trace.records.Shading`; light:
    the (3,) light position of the shadow rays (read with looks.shadows only).
    """
    nxt, per = runs
    W, H, tile = view.W, view.H, view.tile
    ntiles = ((W + tile - 1) // tile) * ((H + tile - 1) // tile)
    mb = np.empty(SCRATCH, np.int32)
    while True:
        t0 = atomic_add(nxt, 0, np.int64(1)) * per
        if t0 >= ntiles:
            break
        for ti in range(t0, min(t0 + per, ntiles)):
            _render_tile(grids, view, looks, light, ti, out, mb)


def dda_render(grids, view, looks, light, out, threads=1):
    """Render the view into out on ``threads`` threads (gridrt.threads.on_threads), each running
    :func:`dda_tiles`; they share the frame's tiles in runs through one counter (tile_runs).  The same
    buffers bit for bit on any number of threads: no pixel depends on which thread renders it."""
    runs = tile_runs(view)

    def work(k):
        dda_tiles(grids, view, looks, light, runs, out)

    on_threads(threads, work)


def _check_grid_tris(grid, tris):
    if not isinstance(grid, Grid):
        raise InputError(f"expected a Grid (from build_grid or GridBuilder.build), got {type(grid).__name__}")
    grid.check_current()
    if isinstance(tris, (list, tuple)):  # nested sequences, as build_grid takes them
        try:
            tris = np.asarray(tris)
        except ValueError:  # ragged: refused below, as any other non-array
            pass
    if not isinstance(tris, np.ndarray) or tris.dtype.kind not in "fiu" or tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise InputError(f"triangles must be the (F,3,3) array the grid was built from, got "
                         f"{getattr(tris, 'shape', None)} {getattr(tris, 'dtype', type(tris))}")
    if tris.shape[0] != grid.n_triangles:
        raise InputError(f"the grid was built over {grid.n_triangles} triangles but {tris.shape[0]} were given")
    if tris.dtype == np.float32 and not grid.origin.any():
        return np.ascontiguousarray(tris)  # the grid's own triangles (the frame pipeline's path)
    if tris.dtype.kind == "f" and not np.isfinite(tris).all():
        raise InputError("triangles contain NaN or infinity")
    if grid.origin.any():
        # the grid lives in a frame centred on the scene: move the (world) triangles there in float64
        return np.ascontiguousarray(tris.astype(np.float64) - grid.origin, dtype=np.float32)
    return np.ascontiguousarray(tris, dtype=np.float32)


@dataclass
class Hits:
    """Per-ray results: t (N,) float64 (inf: miss), tri (N,) int32 (-1: miss), u, v (N,) float64."""

    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray


#: rays per chunk of a batch cast: a batch's rays are checked, converted to float64, moved into
#: the grid's frame and cast this many at a time, so the scratch is bounded whatever the batch size
CAST_CHUNK = 1 << 18
#: bytes per ray of a cast's results: t, u, v float64 and tri int32
HIT_BYTES = 28
#: scratch bytes per ray of a chunk, an upper bound: float64 origins and directions (48), with odd
#: directions their indices and exponents (12) and the re-cast of those rays (origins, directions,
#: results, temporaries: 93), then the grouping into packets (gridrt.trace.batch): a flag, the rows
#: left, their keys, their order and the rows in that order (33), the table of rays_per_bin (up to
#: 4): 190, with room for numpy's own temporaries (measured with tracemalloc: at most 140, odd
#: directions re-cast and the rays left sorted; 82 without odd directions)
CAST_SCRATCH_BYTES = 240


def cast_bytes(n, chunk=None):
    """Bytes a cast of ``n`` rays allocates: its results plus the scratch of one chunk."""
    return HIT_BYTES * n + CAST_SCRATCH_BYTES * min(n, CAST_CHUNK if chunk is None else chunk)


def cast_rays_within(nbytes, chunk=None):
    """The most rays a cast can take within ``nbytes`` (:func:`cast_bytes`), 0 when not one."""
    chunk = CAST_CHUNK if chunk is None else chunk
    if nbytes >= cast_bytes(chunk, chunk):
        return int((nbytes - CAST_SCRATCH_BYTES * chunk) // HIT_BYTES)
    return int(max(0, nbytes) // (HIT_BYTES + CAST_SCRATCH_BYTES))


def cast_batch(grid, tris, origins, dirs, origin=None, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False,
               threads=None, max_bytes=None, chunk=None, packets=True, max_cells=None,
               packet_precision="float64") -> Hits:
    """Cast a batch of rays through ``grid`` over ``tris``, its own C-contiguous (F,3,3) float32
    triangles in the grid's frame (what :func:`_check_grid_tris` returns); ray origins are moved
    into that frame by subtracting ``origin`` ((3,) float64; None: the frame is the world's) in
    float64.  The implementation behind :func:`cast_rays` and ``RayCaster.cast``.

    Memory: the results (:data:`HIT_BYTES` a ray) plus a scratch of one chunk of ``chunk``
    (default :data:`CAST_CHUNK`) rays; the caller's arrays are read in place, chunk by chunk.  A
    batch whose results and scratch exceed ``max_bytes`` (default: GridParams' max_bytes default)
    is refused before anything is allocated.  Every check, including the values of every ray (a
    streaming pass, one chunk at a time), is made before the first kernel runs.

    Coherent runs of rays are traced as CGT packets (gridrt.trace.batch): ``packets=False`` traces
    every ray on its own; ``max_cells`` (default :data:`gridrt.trace.batch.MAX_CELLS`) is the
    widest slice, in cells, a run's bounds may cover to be traced as a packet.  The hits are the
    same either way.  ``packet_precision`` "float32" runs the packets' triangle tests in float32
    (see gridrt.trace.batch; RenderParams.packet_precision)."""
    if not isinstance(grid, Grid):
        raise InputError(f"expected a Grid (from build_grid or GridBuilder.build), got {type(grid).__name__}")
    grid.check_current()
    if not (isinstance(tris, np.ndarray) and tris.dtype == np.float32 and tris.flags.c_contiguous
            and tris.shape == (grid.n_triangles, 3, 3)):
        raise InputError("cast_batch needs the grid's own C-contiguous (F,3,3) float32 triangles (see cast_rays)")
    o, d = check_rays(origins, dirs)
    tmin = float(tmin)
    tmax = float(tmax)
    if math.isnan(tmin) or math.isnan(tmax) or tmin < 0 or tmax < tmin:
        raise InputError(f"need 0 <= tmin <= tmax, got tmin={tmin}, tmax={tmax}")
    threads = check_threads(threads)
    if not isinstance(packets, (bool, np.bool_)):
        raise InputError(f"packets must be True or False, got {packets!r}")
    if max_cells is None:
        max_cells = MAX_CELLS
    elif not (isinstance(max_cells, (int, float, np.integer, np.floating)) and not isinstance(max_cells, bool)
              and math.isfinite(max_cells) and max_cells >= 0):
        raise InputError(f"max_cells must be a finite number >= 0, got {max_cells!r}")
    max_cells = float(max_cells) if packets else 0.0
    if packet_precision not in PACKET_PRECISIONS:
        raise InputError(f"unknown packet precision {packet_precision!r}; choose one of "
                         f"{', '.join(PACKET_PRECISIONS)}")
    f32 = packet_precision == "float32"
    frame = as_origin(origin)  # (RayCaster's frame, or grid.origin: both engine-made)
    frame = frame if frame.any() else None
    chunk = CAST_CHUNK if chunk is None else _positive_int("chunk", chunk)
    budget = DEFAULT_MAX_BYTES if max_bytes is None else _positive_int("max_bytes", max_bytes)
    N = len(o)
    need = cast_bytes(N, chunk)
    if need > budget:
        raise InputError(
            f"casting {N} rays at once needs {need / 2**20:.0f} MiB ({HIT_BYTES} bytes a ray for the hits, plus "
            f"scratch), above the memory budget max_bytes={budget / 2**20:.0f} MiB; cast fewer rays at a time "
            f"or raise max_bytes")
    check_fits(need, f"casting {N:,} rays", "hits, triangle ids, barycentrics and scratch",
               lambda avail: f"cast in batches of at most {cast_rays_within(avail, chunk):,} rays")
    for s in range(0, N, chunk):
        check_ray_values(o[s : s + chunk], d[s : s + chunk], s, frame)
    hits = Hits(np.empty(N), np.empty(N, np.int32), np.empty(N), np.empty(N))
    use_threads(threads)
    g = grid_arrays(grid, tris)
    wt, ah = bool(watertight), bool(any_hit)
    with launch_guard():
        for s in range(0, N, chunk):
            e = min(N, s + chunk)
            if frame is None:
                oc = np.ascontiguousarray(o[s:e], dtype=np.float64)
            else:
                oc = np.subtract(o[s:e], frame, dtype=np.float64, order="C")  # (any layout in: one kernel)
            dc = np.ascontiguousarray(d[s:e], dtype=np.float64)
            out = (hits.t[s:e], hits.tri[s:e], hits.u[s:e], hits.v[s:e])
            # directions far from unit length are rescaled by exact powers of two (t scales back
            # exactly), so the traversal never sees components whose inverse overflows:
            # frexp exponent < -100 or > 100, i.e. a largest component below 2**-101 or from 2**100
            odd = odd_directions(dc)  # (one pass in a kernel: the numpy expression took 10% of a cast)
            d_odd = dc[odd]
            ex = np.frexp(np.abs(d_odd).max(axis=1))[1]
            if len(odd):
                if np.may_share_memory(dc, d):
                    dc = dc.copy()  # (never write to the caller's array)
                dc[odd] = np.ldexp(d_odd, -ex[:, None])
            cast_grouped(g, oc, dc, tmin, tmax, wt, ah, out, max_cells, f32)
            for x in np.unique(ex):
                rows = odd[ex == x]
                # t = t' * 2**-x for d' = d * 2**-x; a hit beyond float64's range is no hit
                lo_t, hi_t = np.ldexp(np.array([tmin, tmax]), int(x))
                sub = [np.empty(len(rows)), np.empty(len(rows), np.int32), np.empty(len(rows)), np.empty(len(rows))]
                cast_grouped(g, oc[rows], dc[rows], float(lo_t), float(hi_t), wt, ah, sub, max_cells, f32)
                with np.errstate(over="ignore"):
                    ts = np.ldexp(sub[0], -int(x))
                gone = ~np.isfinite(ts)
                out[0][rows] = np.where(gone, np.inf, ts)
                out[1][rows] = np.where(gone, -1, sub[1])
                out[2][rows] = np.where(gone, 0.0, sub[2])
                out[3][rows] = np.where(gone, 0.0, sub[3])
    return hits


def cast_rays(grid, tris, origins, dirs, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False, threads=None,
              max_bytes=None, packets=True, packet_precision="float64"):
    """Cast rays through a built grid. Returns Hits. Directions need not be unit length
    (t is then in units of the given direction).  Rays are cast in chunks of CAST_CHUNK, so the
    memory needed is the results (28 bytes a ray) plus a bounded scratch; a batch above
    ``max_bytes`` (default 2 GiB, GridParams' default budget) is refused before anything is
    allocated (see :func:`cast_batch`).  Coherent runs of rays go through CGT packets
    (``packets=False``: every ray on its own); the hits do not depend on it, nor on the rays'
    order.  ``packet_precision="float32"``: the packets' triangle tests in float32 (see
    :func:`cast_batch`)."""
    tris = _check_grid_tris(grid, tris)
    return cast_batch(grid, tris, origins, dirs, getattr(grid, "origin", None), tmin, tmax, watertight, any_hit,
                      threads, max_bytes, packets=packets, packet_precision=packet_precision)


@dataclass
class Looks:
    """What the ``material`` shading mode needs beyond the grids (gridrt.trace.material).

    tris     (F, 3, 3) float32: the scene's triangles in the coordinates the grids were built in,
             indexed by scene id (for one grid without ids: the grid's own triangles)
    surface  gridrt.scene.surface.Surface of those triangles, or None (one default material)
    normals  (F, 3, 3) float32 shading normals per corner, or None (geometric normals)
    lights   (L, 8) float64 lights in world coordinates (gridrt.scene.surface), or None / empty
             (the default light)
    """

    tris: np.ndarray
    surface: object = None
    normals: np.ndarray | None = None
    lights: np.ndarray | None = None


def _check_looks(looks, n_scene):
    if not isinstance(looks, Looks):
        raise InputError(f"looks must be a gridrt.trace.render.Looks, got {type(looks).__name__}")
    tris = looks.tris
    if not (isinstance(tris, np.ndarray) and tris.dtype == np.float32 and tris.shape == (n_scene, 3, 3)):
        raise InputError(f"looks.tris must be the scene's ({n_scene}, 3, 3) float32 triangles, got "
                         f"{getattr(tris, 'shape', None)} {getattr(tris, 'dtype', type(tris))}")
    if not np.isfinite(tris).all():
        raise InputError("looks.tris contain NaN or infinity")
    surface = looks.surface
    if surface is not None and (not isinstance(surface, Surface) or surface.n_triangles != n_scene):
        raise InputError(f"looks.surface must be a Surface of the scene's {n_scene} triangles, got "
                         f"{getattr(surface, 'n_triangles', type(surface).__name__)}")
    normals = looks.normals
    if normals is not None:
        if not (isinstance(normals, np.ndarray) and normals.dtype == np.float32 and normals.shape == (n_scene, 3, 3)):
            raise InputError(f"looks.normals must be ({n_scene}, 3, 3) float32, got "
                             f"{getattr(normals, 'shape', None)} {getattr(normals, 'dtype', type(normals))}")
        if not np.isfinite(normals).all():
            raise InputError("looks.normals contain NaN or infinity")
    return (np.ascontiguousarray(tris), surface, None if normals is None else np.ascontiguousarray(normals),
            as_lights(looks.lights, "looks.lights"))


#: the light guide's squares (Renderer.light_guide): pixels on a side
GUIDE_BLOCK = 8
#: the light guide's factor of a light the square's centre does not see
GUIDE_FLOOR = 0.1


def segment_buffers(n):
    """:class:`ShadowSegments` for n segments."""
    return ShadowSegments(np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.uint8), np.empty(n))


@dataclass
class RenderResult:
    """image (H,W,4) uint8; t (H,W) float32 hit distance (inf: miss); tri (H,W) int32 (-1: miss);
    cost (H,W) int32 triangle tests per primary ray; cells (H,W) int32 cells visited; stats
    RenderStats (gridrt.stats); hdr (H,W,3) float32, the material mode with shadows only (else
    None): each hit pixel's colour before it is clamped to 1 and rounded into the image (-1 for
    a miss), so that the mean of several draws of the lights
    (RenderParams.light_seed) is that of their unclamped estimates.  The image and hdr are the
    renderer's buffers, overwritten by its next render."""

    image: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    cost: np.ndarray
    cells: np.ndarray
    stats: RenderStats
    hdr: np.ndarray | None = None


class Renderer:
    """Holds the output buffers from frame to frame, and the material pass's shadow buffers;
    ``render`` fills them."""

    def __init__(self):
        self._bufs = None
        self._shadow = None  # ((W, H), ShadowBuffers): the material pass's with shadows
        self._drawn = None  # (lit, factor, ShadowSegments of W * H * K): the lights drawn per pixel, their segments
        self._probes = None  # ((W, H), pixels): the centres of the light guide's squares (light_guide)
        self.guide = None    # (guide, squares a row) of the last render that drew lights (light_guide)
        self._lightmaps = LightMaps()   # the first grid's point lights' maps (gridrt.trace.lightmap)
        self.shadow_clear = 0   # shadow segments of the last render that a light map showed clear (not cast there)
        self.shadow_blocked = 0   # and those it showed blocked (not cast at all)

    def buffers(self, W, H):
        if self._bufs is None or self._bufs[0].shape[:2] != (H, W):
            self._bufs = (
                np.zeros((H, W, 4), np.uint8),
                np.zeros((H, W), np.float32),
                np.zeros((H, W), np.int32),
                np.zeros((H, W), np.int32),
                np.zeros((H, W), np.int32),
            )
        return self._bufs

    def shadow_buffers(self, W, H):
        """The material pass's buffers for shadows at W x H (:class:`ShadowBuffers`), kept from
        frame to frame (187 bytes a pixel): fresh ones cost a frame at 1024x1024 187 MiB of memory
        the system must zero and map page by page.  The pixels' tile order is filled once."""
        if self._shadow is None or self._shadow[0] != (W, H):
            self._shadow = None  # (the old ones go first)
            n = W * H
            order = np.empty(n, np.int64)
            tile_order(n, W, 0, order)
            f32 = np.float32
            self._shadow = ((W, H), ShadowBuffers(
                HitPoints(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3), f32), np.empty((n, 3), f32),
                          np.empty((n, 3), f32)),
                ShadowRays(np.empty(n, np.uint8), np.empty(n, np.float64)),
                order,
                segment_buffers(n),
                (np.empty(n), np.empty(n, np.int32), np.empty(n), np.empty(n)),
                np.empty(n, bool)))
        return self._shadow[1]

    def drawn_buffers(self, n, K):
        """The buffers of lights drawn per pixel, K a pixel of n: :class:`Draws`' lit (n, K) int32
        and factor (n, K) float64, and :class:`ShadowSegments` of n * K, kept from frame to frame."""
        if self._drawn is None or self._drawn[0].shape != (n, K):
            self._drawn = None
            self._drawn = (np.empty((n, K), np.int32), np.empty((n, K)), segment_buffers(n * K))
        return self._drawn

    def render(self, grid, tris, camera, params: RenderParams | None = None, second=None,
               looks: Looks | None = None) -> RenderResult:
        """Render ``grid`` over ``tris``; ``second`` = (grid_b, tris_b, ids_a, ids_b) adds a second
        grid traversed together with the first (static and moving parts of one scene); the tri
        buffer then holds scene ids through ids_a / ids_b ((F_a,), (F_b,) int32).

        ``looks`` (:class:`Looks`) gives the ``material`` mode the scene's triangles, surface,
        normals and lights; shading "auto" is "material" when it has a surface, else "lambert".

        ``tris``, ``camera`` and ``params.light`` are in world coordinates; a grid built in a
        frame centred on the scene (``grid.origin``, see build_grid) gets them moved there."""
        params = params or RenderParams()
        tris = _check_grid_tris(grid, tris)
        n_scene = len(tris) + (len(second[1]) if second is not None else 0)
        if looks is not None:
            looks = _check_looks(looks, n_scene)
        shading = params.resolved(looks is not None and looks[1] is not None and looks[1].has_looks)
        if shading == "material" and looks is None:
            if second is not None:
                raise InputError("the material shading of two grids needs looks= (the scene's triangles by scene id)")
            looks = (tris, None, None, as_lights(None))
        if not isinstance(camera, Camera):
            raise InputError(f"camera must be an gridrt.Camera, got {type(camera).__name__}")
        camera = camera.moved(-grid.origin)  # world -> the grid's frame (a no-op at origin 0)
        if second is not None:
            grid_b, tris_b, ids_a, ids_b = second
            if not np.array_equal(grid_b.origin, grid.origin):
                raise InputError(f"the two grids were built in different frames (grid.origin {grid.origin.tolist()} "
                                 f"and {grid_b.origin.tolist()}): build the second with "
                                 "build_grid(..., origin=first.origin)")
            tris_b = _check_grid_tris(grid_b, tris_b)
            ids_a = np.ascontiguousarray(ids_a, np.int32)
            ids_b = np.ascontiguousarray(ids_b, np.int32)
            if ids_a.shape != (len(tris),) or ids_b.shape != (len(tris_b),):
                raise InputError("triangle id maps must have one entry per triangle of each grid")
            grids = grid_tuple((grid, tris, ids_a), (grid_b, tris_b, ids_b))
            lo_s = np.minimum(grid.spec.scene_lo, grid_b.spec.scene_lo)
            hi_s = np.maximum(grid.spec.scene_hi, grid_b.spec.scene_hi)
        else:
            grids = (grid_arrays(grid, tris),)
            lo_s, hi_s = grid.spec.scene_lo, grid.spec.scene_hi
        threads = check_threads(params.threads)
        W, H = params.width, params.height
        img, tb, ib, cb, nb = self.buffers(W, H)
        basis = camera.basis()
        diag = float(np.linalg.norm(hi_s - lo_s))
        if params.light is not None:
            light = np.asarray(params.light, np.float64) - grid.origin  # world -> the grid's frame
        else:
            light = default_light(diag, camera)
        use_threads(threads)
        material = shading == "material"
        shadows = bool(params.shadows) and not material
        v = make_view(basis, W, H, params.tile)
        look = make_shading(SHADING_CODES[shading], shadows, SHADOW_OFFSET * diag, params.watertight)
        out = Buffers(img, tb, ib, cb, nb)
        t0 = time.perf_counter()
        if params.traversal == "cgt":
            # far None where every ray starts near every grid: the kernels without the far-ray path
            near = near_all([(g.lo, g.hi) for g in grids], [basis[0]] + ([light] if shadows else []))
            pk = make_packets(params.packet_precision == "float32", *params.packet, far=not near)
            # light None: the CGT kernel without its shadow path (compiles faster)
            sums = cgt_render(grids, v, look, light if shadows else None, pk, out, threads)
        else:
            dda_render(grids, v, look, light, out, threads)
        shade_ms, n_lights, n_shadow, hdr = 0.0, (1 if params.shadows else 0), None, None
        if material:
            t1 = time.perf_counter()
            n_lights, n_shadow = self._shade_material(grids, looks, params, camera, grid.origin, light, diag, threads)
            shade_ms = (time.perf_counter() - t1) * 1e3
            if params.shadows:
                hdr = self.shadow_buffers(W, H).hp.acc.reshape(H, W, 3)
        ms = (time.perf_counter() - t0) * 1e3
        n = W * H
        if n_shadow is None:  # lambert's shadow rays (one per hit facing the light) are not counted
            n_shadow = None if params.shadows else 0
        extra = dict(lights=n_lights, shadow_rays_per_pixel=None if n_shadow is None else n_shadow / n,
                     shade_ms=shade_ms)
        stats = RenderStats(
            render_ms=ms,
            mrays=n / (ms * 1e3) if ms > 0 else float("nan"),
            hit_fraction=float((ib >= 0).mean()),
            tests_per_ray=float(cb.mean()),
            cells_per_ray=float(nb.mean()),
            render_threads=threads,
            traversal=params.traversal,
            **extra,
        ) if params.traversal == "dda" else RenderStats(
            # the CGT kernel sums (hits, costbuf, cellbuf, fallback rays) as it writes the buffers
            render_ms=ms,
            mrays=n / (ms * 1e3) if ms > 0 else float("nan"),
            hit_fraction=int(sums[0]) / n,
            tests_per_ray=int(sums[1]) / n,
            cells_per_ray=int(sums[2]) / n,
            render_threads=threads,
            traversal=params.traversal,
            split_rays=int(sums[3]),
            **extra,
        )
        return RenderResult(img, tb, ib, cb, nb, stats, hdr)

    def _shade_material(self, grids, looks, params, camera, origin, default, diag, threads):
        """The material pass over the hits in the tri buffer (gridrt.trace.material); returns (lights
        used, shadow rays cast)."""
        stris, surface, normals, lights = looks
        W, H = params.width, params.height
        img, tb, ib, cb, nb = self.buffers(W, H)
        if params.light is not None or len(lights) == 0:
            # an explicit light replaces the scene's; a scene without lights gets the default one
            lights = np.array([[0.0, *default, 1.0, 1.0, 1.0, 0.0]])
        else:
            lights = lights.copy()
            point = lights[:, 0] == 0.0
            lights[point, 1:4] -= origin  # world -> the grid's frame
        surf = surface_arrays(stris, surface, normals)
        deferred = bool(params.shadows)
        if deferred:
            sb = self.shadow_buffers(W, H)
            hp = sb.hp
        else:
            hp = HitPoints(np.empty((0, 3)), np.empty((0, 3)), np.empty((0, 3), np.float32),
                           np.empty((0, 3), np.float32), np.empty((0, 3), np.float32))
        v = make_view(camera.basis(), W, H, params.tile)
        shade(v, ib, surf, lights, deferred, img, hp, threads)
        if not deferred:
            return len(lights), 0
        rays, order, segs, out_b = sb.rays, sb.order, sb.segs, sb.out

        # of several grids (the static/moving split), each traces only the segments that may meet
        # its box: a moving part's grid is often small, and most segments pass it by
        boxes = near_boxes(grids) if 1 < len(grids) <= 8 else np.empty((0, 7))
        tvd, acc = hp.tvd, hp.acc
        off, far = SHADOW_OFFSET * diag, 2.0 * max(diag, 1e-300)
        max_cells = SHADOW_MAX_CELLS if params.traversal == "cgt" else 0.0
        f32 = params.packet_precision == "float32"
        cast, start = 0, None

        def blocked_of(segs, s0, m, shown=False):
            """sb.blocked[:m]: which of segments s0 .. s0 + m of segs hit something in any grid
            (shown: sb.blocked[:m] holds those a light map showed blocked, leave_clear)."""
            o, d, marks = segs.o[s0:s0 + m], segs.d[s0:s0 + m], segs.grids[s0:s0 + m]
            blocked = sb.blocked[:m]
            if not shown:
                blocked[:] = False
            live = np.empty(m, np.int64)
            for gi, g in enumerate(grids):  # any hit in any grid shadows: the segments not blocked yet
                n = live_segments(blocked, marks, (1 << gi) if gi < 8 else -1, live)
                if n == 0:
                    continue
                every = n == m
                out = tuple(a[:m] for a in out_b)   # (the results in the segments' rows)
                cast_grouped(g, o, d, 0.0, 1.0, bool(params.watertight), True, out, max_cells, f32, tri_only=True,
                             rows=None if every else live[:n], sorted_max_cells=SHADOW_SORTED_MAX_CELLS)
                mark_blocked(live, n, every, out[1], blocked)
            return blocked

        # point lights over the first grid's triangles, the same as in an earlier frame: their
        # segments that a light map shows clear are left out of that grid's casts (bit 0), and those
        # it shows blocked out of every grid's
        maps = self._lightmaps.for_lights(grids[0], lights, diag)
        self.shadow_clear = self.shadow_blocked = 0

        def leave_clear(segs, s0, m, li):
            """Clear bit 0 of segments s0 .. s0 + m of segs (light li's) that its map shows clear,
            and write sb.blocked[:m]: those it shows blocked.  Whether it wrote them (a map)."""
            if maps[li] is None or m == 0:
                return False
            cl, bl = clear_lit(maps[li].arrays(grids[0].tris), hp, segs.rows[s0:s0 + m], off, segs.o[s0:s0 + m],
                               segs.d[s0:s0 + m], 1, segs.grids[s0:s0 + m], sb.blocked[:m])
            self.shadow_clear += int(cl)
            self.shadow_blocked += int(bl)
            return True

        k = params.light_samples
        if k and len(lights) > 1:  # k lights drawn per hit pixel, weighted to keep the mean: every
            # light's segments at once, each light's in a run of their own
            guide, bw, probes = self.light_guide(W, H, lights, hp, off, far, boxes, blocked_of)
            self.guide = (guide, bw)
            cast += probes
            lit, factor, segs = self.drawn_buffers(W * H, min(k, len(lights)))
            draws = make_draws(k, draw_shift(params.light_seed), lit, factor, guide, GUIDE_BLOCK, bw)
            start = drawn_segments(lights, hp, W, draws, off, far, order, segs, boxes)
        # each light's shadow rays in tiles of the image (TILE x TILE pixels, sb.order): the batch
        # caster takes them in runs of RUN = TILE^2 in this order, and a run of one tile is a narrow
        # packet where a run of a row's pixels is a wide one (or single rays)
        for li in range(len(lights)):
            if start is None:
                s0, m = 0, int(light_segments(lights, li, hp, off, far, order, rays, segs, boxes))
            else:
                s0, m = int(start[li]), int(start[li + 1] - start[li])
            shown = leave_clear(segs, s0, m, li)
            cast += m
            blocked = blocked_of(segs, s0, m, shown)
            add_light(segs.rows[s0:s0 + m], blocked, segs.weight[s0:s0 + m], tvd, float(lights[li, 4]),
                      float(lights[li, 5]), float(lights[li, 6]), acc)
        compose(W, H, acc, img)
        return len(lights), cast

    def light_guide(self, W, H, lights, hp, off, far, boxes, blocked_of):
        """(guide, blocks a row, rays cast) for the draws of lights per pixel: in each GUIDE_BLOCK x
        GUIDE_BLOCK square of the image, the hit at its centre pixel casts a shadow ray towards
        every light that lights it (drawn_segments with k = 0), and guide[block, light] is
        GUIDE_FLOOR where that ray is blocked, else 1 (also where the centre is a miss or the
        light does not light it): lights that the square's centre does not see are drawn less
        often there, and weighted up when drawn (the estimate stays unbiased)."""
        B, L = GUIDE_BLOCK, len(lights)
        bw, bh = -(-W // B), -(-H // B)
        if self._probes is None or self._probes[0] != (W, H):
            by, bx = np.divmod(np.arange(bw * bh), bw)
            centre = np.minimum(by * B + B // 2, H - 1) * W + np.minimum(bx * B + B // 2, W - 1)
            tiles = np.empty(bw * bh, np.int64)
            tile_order(bw * bh, bw, 0, tiles)   # (the blocks in tiles: neighbouring rays together)
            self._probes = ((W, H), centre[tiles].astype(np.int64))
        probes = self._probes[1]
        n = len(probes)
        draws = make_draws(0, 0.0, np.empty((n, L), np.int32), np.empty((n, L)))
        segs = segment_buffers(n * L)
        start = drawn_segments(lights, hp, W, draws, off, far, probes, segs, boxes)
        guide = np.ones((bw * bh, L))
        for li in range(L):
            s0, m = int(start[li]), int(start[li + 1] - start[li])
            if m:
                rows = segs.rows[s0:s0 + m][blocked_of(segs, s0, m)]
                guide[(rows // W) // B * bw + (rows % W) // B, li] = GUIDE_FLOOR
        return guide, bw, int(start[L])


def default_light(diag, camera):
    """Above and to the right of the camera, at the scene's scale: eye + (0.6 right + up) * diag,
    where diag is the length of the scene's bounding-box diagonal."""
    b = camera.basis()
    return b[0] + (0.6 * b[2] + 1.0 * b[3]) * diag


def render(grid, tris, camera, params: RenderParams | None = None) -> RenderResult:
    """One-shot render (allocates its buffers); see Renderer for frame-to-frame reuse."""
    return Renderer().render(grid, tris, camera, params)
