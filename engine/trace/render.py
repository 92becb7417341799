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

The unit geometric normal is normalize((v1 - v0) x (v2 - v0)).
"""

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..arrays import as_rays
from ..config import RenderParams
from ..errors import InputError
from ..threads import check_threads, use_threads
from .traverse import MAILBOX, trace_ray
from ..camera import pixel_dir

BACKGROUND = (0.12, 0.13, 0.16)
ALBEDO = (0.85, 0.78, 0.66)
AMBIENT = 0.15
COST_SCALE = 64.0
#: shadow-ray origins move off the surface by this fraction of the scene's bounding-box diagonal
SHADOW_OFFSET = 1e-6
_NO_IDS = np.zeros(0, np.int32)
SHADING_CODES = {"lambert": 0, "normal": 1, "cost": 2}


@njit(cache=True)
def _u8(c):
    v = int(c * 255.0 + 0.5)
    return np.uint8(0 if v < 0 else (255 if v > 255 else v))


@njit(cache=True, _nrt=False)
def _normal(tris, f):
    e1x = np.float64(tris[f, 1, 0]) - tris[f, 0, 0]
    e1y = np.float64(tris[f, 1, 1]) - tris[f, 0, 1]
    e1z = np.float64(tris[f, 1, 2]) - tris[f, 0, 2]
    e2x = np.float64(tris[f, 2, 0]) - tris[f, 0, 0]
    e2y = np.float64(tris[f, 2, 1]) - tris[f, 0, 1]
    e2z = np.float64(tris[f, 2, 2]) - tris[f, 0, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    n = math.sqrt(nx * nx + ny * ny + nz * nz)
    if n == 0.0:
        return 0.0, 0.0, 0.0
    return nx / n, ny / n, nz / n


@njit(cache=True, _nrt=False)
def trace_two(
    tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
    tris_b, lo_b, hi_b, cell_b, inv_cell_b, dims_b, cell_start_b, tri_ids_b, macro_b, mdims_b, macro_full_b,
    has_b, ox, oy, oz, dx, dy, dz, tmin, tmax, watertight, any_hit, mb,
):
    """Nearest hit over grid A and (when has_b) grid B: (which 0/1, tri, t, u, v, cells, tests)."""
    f, t, u, v, nc, nt = trace_ray(
        tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
        ox, oy, oz, dx, dy, dz, tmin, tmax, watertight, any_hit, mb,
    )
    if not has_b or (any_hit and f >= 0):
        return 0, f, t, u, v, nc, nt
    f2, t2, u2, v2, nc2, nt2 = trace_ray(
        tris_b, lo_b, hi_b, cell_b, inv_cell_b, dims_b, cell_start_b, tri_ids_b, macro_b, mdims_b, macro_full_b,
        ox, oy, oz, dx, dy, dz, tmin, t if f >= 0 else tmax, watertight, any_hit, mb,
    )
    if f2 >= 0:
        return 1, f2, t2, u2, v2, nc + nc2, nt + nt2
    return 0, f, t, u, v, nc + nc2, nt + nt2


@njit(cache=True, parallel=True)
def render_kernel(
    tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
    tris_b, lo_b, hi_b, cell_b, inv_cell_b, dims_b, cell_start_b, tri_ids_b, macro_b, mdims_b, macro_full_b,
    has_b, ids_a, ids_b, basis, W, H, tile, mode, shadows, light, off, watertight,
    img, tbuf, idbuf, costbuf, cellbuf,
):
    """Render W x H pixels into img (H,W,4) uint8, tbuf (H,W) float32, idbuf (H,W) int32,
    costbuf (H,W) int32 (triangle tests) and cellbuf (H,W) int32 (cells visited).

    Grid A over tris, and with has_b also grid B over tris_b (a scene split into static and
    moving parts); ids_a / ids_b map each part's triangle index to the scene's (used when
    has_b).  off: shadow-ray origin offset along the normal.
    """
    ntx = (W + tile - 1) // tile
    nty = (H + tile - 1) // tile
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    for ti in prange(ntx * nty):
        mb = np.empty(MAILBOX, np.int32)
        tx0 = (ti % ntx) * tile
        ty0 = (ti // ntx) * tile
        for y in range(ty0, min(ty0 + tile, H)):
            for x in range(tx0, min(tx0 + tile, W)):
                dx, dy, dz = pixel_dir(basis, W, H, x, y)
                which, f, t, u, v, nc, nt = trace_two(
                    tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
                    tris_b, lo_b, hi_b, cell_b, inv_cell_b, dims_b, cell_start_b, tri_ids_b, macro_b, mdims_b,
                    macro_full_b, has_b, ex, ey, ez, dx, dy, dz, 0.0, np.inf, watertight, False, mb,
                )
                tbuf[y, x] = np.float32(t)
                if f >= 0 and has_b:
                    idbuf[y, x] = ids_b[f] if which == 1 else ids_a[f]
                else:
                    idbuf[y, x] = f
                costbuf[y, x] = nt
                cellbuf[y, x] = nc
                r = BACKGROUND[0]
                g = BACKGROUND[1]
                b = BACKGROUND[2]
                if mode == 2:
                    h = min(1.0, nt / COST_SCALE)
                    if h < 0.5:
                        r, g, b = 0.0, 2.0 * h, 1.0 - 2.0 * h
                    else:
                        r, g, b = 2.0 * h - 1.0, 2.0 - 2.0 * h, 0.0
                elif f >= 0:
                    if which == 1:
                        nx, ny, nz = _normal(tris_b, f)
                    else:
                        nx, ny, nz = _normal(tris, f)
                    dn = nx * dx + ny * dy + nz * dz
                    if dn > 0.0:
                        nx, ny, nz, dn = -nx, -ny, -nz, -dn
                    if mode == 1:
                        r, g, b = (nx + 1.0) * 0.5, (ny + 1.0) * 0.5, (nz + 1.0) * 0.5
                    else:
                        if not shadows:
                            s = -dn
                        else:
                            px = ex + t * dx
                            py = ey + t * dy
                            pz = ez + t * dz
                            lx = light[0] - px
                            ly = light[1] - py
                            lz = light[2] - pz
                            ld = math.sqrt(lx * lx + ly * ly + lz * lz)
                            s = 0.0
                            if ld > 0.0:
                                lx /= ld
                                ly /= ld
                                lz /= ld
                                s = nx * lx + ny * ly + nz * lz
                                if s > 0.0:
                                    sw, sf, st, su, sv, snc, snt = trace_two(
                                        tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims,
                                        macro_full, tris_b, lo_b, hi_b, cell_b, inv_cell_b, dims_b, cell_start_b,
                                        tri_ids_b, macro_b, mdims_b, macro_full_b, has_b,
                                        px + nx * off, py + ny * off, pz + nz * off, lx, ly, lz,
                                        0.0, ld, watertight, True, mb,
                                    )
                                    if sf >= 0:
                                        s = 0.0
                                else:
                                    s = 0.0
                        k = AMBIENT + (1.0 - AMBIENT) * s
                        r, g, b = ALBEDO[0] * k, ALBEDO[1] * k, ALBEDO[2] * k
                img[y, x, 0] = _u8(r)
                img[y, x, 1] = _u8(g)
                img[y, x, 2] = _u8(b)
                img[y, x, 3] = np.uint8(255)


@njit(cache=True, parallel=True)
def cast_kernel(
    tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
    origins, dirs, tmin, tmax, watertight, any_hit, chunk,
    out_t, out_f, out_u, out_v,
):
    """Nearest hit of each ray (origins, dirs (N,3) float64) into the out_* arrays (N,)."""
    N = origins.shape[0]
    nch = (N + chunk - 1) // chunk
    for ci in prange(nch):
        mb = np.empty(MAILBOX, np.int32)
        for i in range(ci * chunk, min((ci + 1) * chunk, N)):
            f, t, u, v, nc, nt = trace_ray(
                tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
                origins[i, 0], origins[i, 1], origins[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2],
                tmin, tmax, watertight, any_hit, mb,
            )
            out_t[i] = t
            out_f[i] = f
            out_u[i] = u
            out_v[i] = v


def _grid_args(grid):
    s = grid.spec
    return (s.lo, s.hi, s.cell, s.inv_cell, s.dims, grid.cell_start, grid.tri_ids, s.macro, s.mdims, grid.macro_full)


def _check_grid_tris(grid, tris):
    if not isinstance(tris, np.ndarray) or tris.dtype != np.float32 or tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise InputError(f"triangles must be the (F,3,3) float32 array the grid was built from, got "
                         f"{getattr(tris, 'shape', None)} {getattr(tris, 'dtype', type(tris))}")
    if tris.shape[0] != grid.n_triangles:
        raise InputError(f"the grid was built over {grid.n_triangles} triangles but {tris.shape[0]} were given")
    return np.ascontiguousarray(tris)


@dataclass
class Hits:
    """Per-ray results: t (N,) float64 (inf: miss), tri (N,) int32 (-1: miss), u, v (N,) float64."""

    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray


def cast_rays(grid, tris, origins, dirs, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False, threads=None):
    """Cast rays through a built grid. Returns Hits. Directions need not be unit length
    (t is then in units of the given direction)."""
    tris = _check_grid_tris(grid, tris)
    o, d = as_rays(origins, dirs)
    tmin = float(tmin)
    tmax = float(tmax)
    if math.isnan(tmin) or math.isnan(tmax) or tmin < 0 or tmax < tmin:
        raise InputError(f"need 0 <= tmin <= tmax, got tmin={tmin}, tmax={tmax}")
    use_threads(check_threads(threads))
    N = len(o)
    t = np.empty(N)
    f = np.empty(N, np.int32)
    u = np.empty(N)
    v = np.empty(N)
    if N:
        cast_kernel(tris, *_grid_args(grid), o, d, tmin, tmax, bool(watertight), bool(any_hit), 256, t, f, u, v)
    return Hits(t, f, u, v)


@dataclass
class RenderResult:
    """image (H,W,4) uint8; t (H,W) float32 hit distance (inf: miss); tri (H,W) int32 (-1: miss);
    cost (H,W) int32 triangle tests per primary ray; cells (H,W) int32 cells visited; stats dict."""

    image: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    cost: np.ndarray
    cells: np.ndarray
    stats: dict


class Renderer:
    """Holds the output buffers from frame to frame; ``render`` fills them."""

    def __init__(self):
        self._bufs = None

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

    def render(self, grid, tris, camera, params: RenderParams | None = None, second=None) -> RenderResult:
        """Render ``grid`` over ``tris``; ``second`` = (grid_b, tris_b, ids_a, ids_b) adds a second
        grid traversed together with the first (static and moving parts of one scene); the tri
        buffer then holds scene ids through ids_a / ids_b ((F_a,), (F_b,) int32)."""
        params = params or RenderParams()
        tris = _check_grid_tris(grid, tris)
        if second is not None:
            grid_b, tris_b, ids_a, ids_b = second
            tris_b = _check_grid_tris(grid_b, tris_b)
            ids_a = np.ascontiguousarray(ids_a, np.int32)
            ids_b = np.ascontiguousarray(ids_b, np.int32)
            if ids_a.shape != (len(tris),) or ids_b.shape != (len(tris_b),):
                raise InputError("triangle id maps must have one entry per triangle of each grid")
            lo_s = np.minimum(grid.spec.scene_lo, grid_b.spec.scene_lo)
            hi_s = np.maximum(grid.spec.scene_hi, grid_b.spec.scene_hi)
        else:
            grid_b, tris_b, ids_a, ids_b = grid, tris, _NO_IDS, _NO_IDS
            lo_s, hi_s = grid.spec.scene_lo, grid.spec.scene_hi
        threads = check_threads(params.threads)
        W, H = params.width, params.height
        img, tb, ib, cb, nb = self.buffers(W, H)
        basis = camera.basis()
        diag = float(np.linalg.norm(hi_s - lo_s))
        if params.light is not None:
            light = np.asarray(params.light, np.float64)
        else:
            light = default_light(diag, camera)
        use_threads(threads)
        t0 = time.perf_counter()
        render_kernel(
            tris, *_grid_args(grid), tris_b, *_grid_args(grid_b), second is not None, ids_a, ids_b,
            basis, W, H, params.tile, SHADING_CODES[params.shading], bool(params.shadows), light,
            SHADOW_OFFSET * diag, bool(params.watertight), img, tb, ib, cb, nb,
        )
        ms = (time.perf_counter() - t0) * 1e3
        n = W * H
        stats = dict(
            render_ms=ms,
            mrays=n / (ms * 1e3) if ms > 0 else float("nan"),
            hit_fraction=float((ib >= 0).mean()),
            tests_per_ray=float(cb.mean()),
            cells_per_ray=float(nb.mean()),
            render_threads=threads,
        )
        return RenderResult(img, tb, ib, cb, nb, stats)


def default_light(diag, camera):
    """Above and to the right of the camera, at the scene's scale: eye + (0.6 right + up) * diag,
    where diag is the length of the scene's bounding-box diagonal."""
    b = camera.basis()
    return b[0] + (0.6 * b[2] + 1.0 * b[3]) * diag


def render(grid, tris, camera, params: RenderParams | None = None) -> RenderResult:
    """One-shot render (allocates its buffers); see Renderer for frame-to-frame reuse."""
    return Renderer().render(grid, tris, camera, params)
