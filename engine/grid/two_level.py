"""Two-level grids: a coarse uniform grid whose non-empty cells each hold a uniform grid of their
own, its resolution chosen from its own triangle count, all rebuilt from scratch every frame.

Kalojanov, Billeter and Slusallek, "Two-Level Grids for Ray Tracing on GPUs" (Eurographics 2011);
Ize, Shirley and Parker, "Grid Creation Strategies for Efficient Ray Tracing" (RT 2007).

Layout (what :class:`TwoLevelGrid` holds, and the traversal kernels read):

* the top level is a uniform grid (:class:`gridrt.grid.layout.GridSpec`, macro cells of one
  cell) over the padded scene bounds, about ``top_density * triangles`` cells, built by the chosen
  strategy exactly as a uniform grid is (its cell lists are ``top_start``, ``top_ids``);
* top cell ``t`` (linear index as in the uniform grid) holds ``leaf_res[t] = (rx, ry, rz)`` leaf
  cells, about ``leaf_density * n_t`` of them for its ``n_t`` references, shaped like the top cell
  (:func:`sub_dims`), none when it is empty; they are the flat leaf cells
  ``leaf_first[t] .. leaf_first[t + 1] - 1``, leaf ``(a, b, c)`` of ``t`` at
  ``leaf_first[t] + a + rx * (b + ry * c)``;
* the leaf cell lists are CSR: leaf cell ``q`` holds ``tri_ids[cell_start[0, q] : cell_start[0, q + 1]]``.

Leaf geometry: top cell ``(i, j, k)`` spans ``lo + (i, j, k) * cell`` to the next multiple; along
each axis its leaf cells start at ``slo = lo + i * cell`` and measure ``sc = cell / r``
(:func:`leaf_axis`, the one formula both the build and the traversal use).

Membership (what "the same contents" means for the tests): a triangle is in a leaf cell of top
cell ``t`` when it is in ``t`` (the uniform grid's rule on the top level) and its bounding box,
grown by ``INSERT_EPS`` leaf-cell sizes on every side, overlaps the closed leaf-cell box (with
exact insertion: and no separating axis between the triangle and the grown leaf box).  That is
the uniform grid's rule applied to the leaf grid over ``t``'s box, among ``t``'s triangles.

The leaf build runs in two parallel passes over chunks of top cells of about equal reference
counts, each top cell owned by one thread (no atomics, no locks): a count pass (each top cell's
leaf counts and their running sums, its own offsets) and, after a prefix sum over the top cells'
totals, a scatter pass.  Any strategy builds the top level; the leaf passes are the same for all.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..compiles import inner, one_per_types
from ..errors import InputError
from .common import EPS, cell_overlaps
from .layout import Grid
from .strategies.base import timed

INT32_MAX = np.iinfo(np.int32).max
#: chunks of top cells per thread in the leaf passes (load balance over uneven top cells)
CHUNKS_PER_THREAD = 8

#: The top level as the leaf passes read it: its cell lists, start (L, T + 1) int32 CSR offsets
#: per layer and ids (R_top,) int32 triangle ids.
TopCells = namedtuple("TopCells", "start ids")
#: The leaf level as the leaf passes fill it: res (T, 3) int32 leaf cells per axis of each top
#: cell, first (T + 1,) int32 first leaf cell of each top cell, count (N,) int32, start (N + 1,)
#: int32 and tri_ids (R,) int32 the leaf cells' counts, CSR offsets and triangle ids.
LeafLevel = namedtuple("LeafLevel", "res first count start tri_ids")


@njit(cache=True, inline="always")
def leaf_axis(lo, cell, i, r):
    """(start, size, 1 / size) of the leaf cells along one axis of top cell ``i`` (grid start
    ``lo``, top cells of size ``cell``) split into ``r`` leaf cells."""
    sc = cell / r
    return lo + i * cell, sc, 1.0 / sc


@inner(cache=True)
def sub_dims(ex, ey, ez, target, out):
    """out[0:3] = cells along x, y, z for a box of extent (ex, ey, ez) split into about
    ``target`` cubical cells (at least one a side; axes too thin for one cell get one and the
    others share the count), as the uniform grid's own resolution (``build.grid_dims``)."""
    ext = (ex, ey, ez)
    act0 = ex > 0
    act1 = ey > 0
    act2 = ez > 0
    out[0] = 1
    out[1] = 1
    out[2] = 1
    for _ in range(3):
        n = int(act0) + int(act1) + int(act2)
        if n == 0:
            return
        vol = (ex if act0 else 1.0) * (ey if act1 else 1.0) * (ez if act2 else 1.0)
        s = (target / vol) ** (1.0 / n)
        thin = False
        if act0 and ex * s < 1.0:
            act0 = False
            thin = True
        if act1 and ey * s < 1.0:
            act1 = False
            thin = True
        if act2 and ez * s < 1.0:
            act2 = False
            thin = True
        if not thin:
            if act0:
                out[0] = max(1, int(ext[0] * s + 0.5))
            if act1:
                out[1] = max(1, int(ext[1] * s + 0.5))
            if act2:
                out[2] = max(1, int(ext[2] * s + 0.5))
            return


@njit(cache=True, parallel=True)
def leaf_resolution(top_start, cell, active, leaf_density, max_res, n_threads, leaf_res, n_leaf, n_refs):
    """Per top cell t: its references n_refs[t] (over all layers of top_start (L, T+1)), its
    leaf resolution leaf_res[t] (T, 3) int32 (0, 0, 0 when empty) and leaf cell count n_leaf[t]
    (T,) int64.  ``active`` (3,) uint8: the axes of non-zero extent (a flat scene's thin axis
    keeps one leaf cell); each axis is capped at max_res."""
    T = leaf_res.shape[0]
    L = top_start.shape[0]
    ex = cell[0] if active[0] else 0.0
    ey = cell[1] if active[1] else 0.0
    ez = cell[2] if active[2] else 0.0
    for th in prange(n_threads):
        out = np.empty(3, np.int64)
        for t in range(th * T // n_threads, (th + 1) * T // n_threads):
            n = 0
            for l in range(L):
                n += top_start[l, t + 1] - top_start[l, t]
            n_refs[t] = n
            if n == 0:
                leaf_res[t, 0] = 0
                leaf_res[t, 1] = 0
                leaf_res[t, 2] = 0
                n_leaf[t] = 0
                continue
            sub_dims(ex, ey, ez, max(1.0, leaf_density * n), out)
            rx = min(out[0], max_res)
            ry = min(out[1], max_res)
            rz = min(out[2], max_res)
            leaf_res[t, 0] = rx
            leaf_res[t, 1] = ry
            leaf_res[t, 2] = rz
            n_leaf[t] = rx * ry * rz


@njit(cache=True, inline="always")
def _leaf_range(b0, b1, slo, isc, r):
    """Inclusive leaf range [a0, a1] (a0 > a1 when none) of a box [b0, b1] along one axis."""
    a0 = math.floor((b0 - slo) * isc - EPS)
    a1 = math.floor((b1 - slo) * isc + EPS)
    return max(a0, 0), min(a1, r - 1)


@one_per_types
@inner(cache=True, _nrt=False)
def _top_cell_leaves(tris, top, box, leaves, t, a0, exact, scatter, base0):
    """Count (scatter=False) or place (True) the leaf references of top cell t of the grid ``box``
    (layout.GridBox), whose leaf cells are a0 .. a0 + rx*ry*rz - 1 with resolution leaves.res[t].
    leaves.count holds the leaf counts (the count pass leaves them, the scatter pass uses them as
    cursors from zero), leaves.start the CSR offsets (the count pass writes running sums relative
    to the cell's first leaf; the scatter pass reads finished ones, but for the cell's first leaf,
    whose offset start[a0] the thread of the top cell before may still be writing, takes base0).
    Returns the top cell's leaf references."""
    lo, cell, dims = box.lo, box.cell, box.dims
    top_start, top_ids = top.start, top.ids
    count, start, tri_ids = leaves.count, leaves.start, leaves.tri_ids
    res = leaves.res[t]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    tk = t // nxy
    tj = (t - tk * nxy) // nx
    ti = t - tk * nxy - tj * nx
    rx, ry, rz = res[0], res[1], res[2]
    n = rx * ry * rz
    sx, cx, ix = leaf_axis(lo[0], cell[0], ti, rx)
    sy, cy, iy = leaf_axis(lo[1], cell[1], tj, ry)
    sz, cz, iz = leaf_axis(lo[2], cell[2], tk, rz)
    for q in range(n):
        count[a0 + q] = 0
    sub_lo = (sx, sy, sz)
    sub_cell = (cx, cy, cz)
    total = 0
    for l in range(top_start.shape[0]):
        for p in range(top_start[l, t], top_start[l, t + 1]):
            f = top_ids[p]
            x0 = min(np.float64(tris[f, 0, 0]), np.float64(tris[f, 1, 0]), np.float64(tris[f, 2, 0]))
            x1 = max(np.float64(tris[f, 0, 0]), np.float64(tris[f, 1, 0]), np.float64(tris[f, 2, 0]))
            y0 = min(np.float64(tris[f, 0, 1]), np.float64(tris[f, 1, 1]), np.float64(tris[f, 2, 1]))
            y1 = max(np.float64(tris[f, 0, 1]), np.float64(tris[f, 1, 1]), np.float64(tris[f, 2, 1]))
            z0 = min(np.float64(tris[f, 0, 2]), np.float64(tris[f, 1, 2]), np.float64(tris[f, 2, 2]))
            z1 = max(np.float64(tris[f, 0, 2]), np.float64(tris[f, 1, 2]), np.float64(tris[f, 2, 2]))
            i0, i1 = _leaf_range(x0, x1, sx, ix, rx)
            j0, j1 = _leaf_range(y0, y1, sy, iy, ry)
            k0, k1 = _leaf_range(z0, z1, sz, iz, rz)
            for c in range(k0, k1 + 1):
                for b in range(j0, j1 + 1):
                    for a in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, a, b, c, sub_lo, sub_cell):
                            continue
                        q = a0 + a + rx * (b + ry * c)
                        if scatter:
                            tri_ids[(start[q] if q != a0 else base0) + count[q]] = f
                        count[q] += 1
                        total += 1
    if not scatter:
        s = 0
        for q in range(n):
            s += count[a0 + q]
            start[a0 + q + 1] = s
    return total


@njit(cache=True, parallel=True)
def leaf_count(tris, top, box, leaves, exact, bounds, totals):
    """Count pass over the chunks of top cells bounds[ch] .. bounds[ch+1]-1: each non-empty top
    cell's leaf counts into leaves.count, their running sums (relative to the top cell's first
    leaf) into leaves.start[q + 1] and its total into totals (T,) int64 (leaves.tri_ids unused)."""
    leaf_first = leaves.first
    for ch in prange(bounds.shape[0] - 1):
        for t in range(bounds[ch], bounds[ch + 1]):
            a0 = leaf_first[t]
            if leaf_first[t + 1] == a0:
                totals[t] = 0
                continue
            totals[t] = _top_cell_leaves(tris, top, box, leaves, t, a0, exact, False, 0)


@njit(cache=True, parallel=True)
def leaf_scatter(tris, top, box, leaves, exact, bounds, base):
    """Scatter pass: each top cell's leaf offsets moved by its base (base (T,) int64, the
    exclusive prefix sum of the count pass's totals), then its references placed."""
    leaf_first = leaves.first
    start = leaves.start
    for ch in prange(bounds.shape[0] - 1):
        for t in range(bounds[ch], bounds[ch + 1]):
            a0 = leaf_first[t]
            a1 = leaf_first[t + 1]
            if a1 == a0:
                continue
            b = base[t]
            # (start[a0] is the end of the top cell before: that cell's thread moves it)
            for q in range(a0 + 1, a1 + 1):
                start[q] += b
            _top_cell_leaves(tris, top, box, leaves, t, a0, exact, True, b)


def chunk_bounds(n_refs, n_chunks):
    """Top-cell chunk boundaries ((n_chunks + 1,) int64) splitting the references n_refs (T,)
    into about equal shares."""
    T = len(n_refs)
    csum = np.cumsum(n_refs)
    total = int(csum[-1]) if T else 0
    if total == 0:
        return np.array([0, T], np.int64)
    targets = (np.arange(1, n_chunks, dtype=np.int64) * total) // n_chunks
    cuts = np.searchsorted(csum, targets, side="right")
    return np.unique(np.concatenate(([0], cuts, [T]))).astype(np.int64)


def build_leaves(top, tris, exact, leaf_density, threads, bufs, max_bytes, times):
    """The leaf level over the built top-level grid ``top`` (a :class:`Grid` over ``tris``).
    Returns (leaf_res, leaf_first, count, start, tri_ids, references); adds leaf_res_ms,
    leaf_count_ms, leaf_scatter_ms to ``times``.  InputError (before allocating) when the leaf
    cells or references would not fit int32 offsets or ``max_bytes`` (with the top level's
    arrays)."""
    s = top.spec
    T = s.n_cells
    top_bytes = top.memory_bytes()
    with timed(times, "leaf_res_ms"):
        if bufs.res.shape[0] < T:
            bufs.res = np.zeros((int(T * 1.25) + 16, 3), np.int32)
        leaf_res = bufs.res[:T]
        n_leaf = np.empty(T, np.int64)
        n_refs = np.empty(T, np.int64)
        active = (s.scene_hi - s.scene_lo > 1e-9 * max(float((s.scene_hi - s.scene_lo).max()), 1e-300)).astype(np.uint8)
        leaf_resolution(top.cell_start, s.cell, active, float(leaf_density), 1 << 10, min(threads, max(1, T)),
                        leaf_res, n_leaf, n_refs)
        total_leaf = int(n_leaf.sum())
        if total_leaf > INT32_MAX - 1:
            raise InputError(f"the two-level grid would hold {total_leaf} leaf cells, more than int32 offsets allow; "
                             f"lower the leaf density")
        need = top_bytes + 8 * (total_leaf + 1) + 16 * T
        if need > max_bytes:
            raise InputError(
                f"the two-level grid would need {need / 2**20:.0f} MiB ({total_leaf} leaf cells), above the memory "
                f"budget max_bytes={max_bytes / 2**20:.0f} MiB; lower the leaf or top density or raise max_bytes")
        if bufs.first.size < T + 1:
            bufs.first = np.zeros(int(T * 1.25) + 17, np.int32)
        leaf_first = bufs.first[: T + 1]
        leaf_first[0] = 0
        if T:
            np.cumsum(n_leaf, out=leaf_first[1:], dtype=np.int32)
        bounds = chunk_bounds(n_refs, threads * CHUNKS_PER_THREAD if threads > 1 else 1)
        count, start = bufs.leaf_arrays(total_leaf)
    with timed(times, "leaf_count_ms"):
        totals = np.empty(T, np.int64)
        top_cells = TopCells(top.cell_start, top.tri_ids)
        leaves = LeafLevel(leaf_res, leaf_first, count, start, start[:0])
        leaf_count(tris, top_cells, s.box, leaves, exact, bounds, totals)
    with timed(times, "leaf_scatter_ms"):
        base = np.zeros(T, np.int64)
        if T > 1:
            np.cumsum(totals[:-1], out=base[1:])
        refs = int(totals.sum())
        if refs > INT32_MAX:
            raise InputError(f"the two-level grid would hold {refs} leaf references, more than int32 offsets allow; "
                             f"lower the leaf density or use exact insertion")
        need = top_bytes + 8 * (total_leaf + 1) + 16 * T + 4 * refs
        if need > max_bytes:
            raise InputError(
                f"the two-level grid would need {need / 2**20:.0f} MiB ({refs} leaf references), above the memory "
                f"budget max_bytes={max_bytes / 2**20:.0f} MiB; lower the leaf or top density, use exact insertion "
                f"or raise max_bytes")
        tri_ids = bufs.refs(refs)
        leaf_scatter(tris, top_cells, s.box, leaves._replace(tri_ids=tri_ids), exact, bounds, base)
        start[total_leaf] = refs
    return leaf_res, leaf_first, count, start, tri_ids, refs


class TwoLevelGrid(Grid):
    """A built two-level grid (see the module's docstring for the layout).

    As a :class:`Grid`, its ``spec`` is the top level's geometry, ``macro_full`` the top cells'
    occupancy (1: non-empty), and ``cell_start`` (1, N + 1), ``tri_ids``, ``cell_count`` (1, N)
    and ``references`` are the N leaf cells' lists: :meth:`cell_tris` and :meth:`pairs` speak of
    leaf cells.  Besides:

    leaf_res        (T, 3) int32   leaf cells along x, y, z of each top cell (0s: empty)
    leaf_first      (T + 1,) int32 first leaf cell of each top cell (CSR over the top cells)
    top_start, top_ids             the top level's own cell lists (L, T + 1) int32, (R_top,) int32
    top_references  int            (top cell, triangle) references
    """

    kind = "two_level"

    def __init__(self, *, leaf_res, leaf_first, top_start, top_ids, top_references, **kw):
        super().__init__(**kw)
        self.leaf_res = leaf_res
        self.leaf_first = leaf_first
        self.top_start = top_start
        self.top_ids = top_ids
        self.top_references = int(top_references)

    @property
    def n_leaf(self):
        return int(self.leaf_first[-1])

    def leaf_geometry(self, t):
        """(lo (3,), cell (3,), res (3,)) of top cell t's leaf grid, float64 and int64, computed
        as the kernels do (:func:`leaf_axis`)."""
        s = self.spec
        ijk = np.array([t % s.dims[0], (t // s.dims[0]) % s.dims[1], t // (s.dims[0] * s.dims[1])], np.int64)
        res = self.leaf_res[t].astype(np.int64)
        lo = s.lo + ijk * s.cell
        cell = s.cell / np.maximum(res, 1)
        return lo, cell, res

    def top_pairs(self):
        """All (top cell, triangle) pairs as a sorted, duplicate-free (P, 2) int64 array."""
        out = []
        T = self.spec.n_cells
        for l in range(self.top_start.shape[0]):
            start = self.top_start[l].astype(np.int64)
            cells = np.repeat(np.arange(T, dtype=np.int64), np.diff(start))
            out.append(np.stack([cells, self.top_ids[start[0]:start[-1]].astype(np.int64)], axis=1))
        return np.unique(np.concatenate(out), axis=0) if out else np.zeros((0, 2), np.int64)

    def pairs(self):
        """All (leaf cell, triangle) pairs as a sorted, duplicate-free (P, 2) int64 array."""
        start = self.cell_start[0].astype(np.int64)
        N = start.shape[0] - 1
        cells = np.repeat(np.arange(N, dtype=np.int64), np.diff(start))
        p = np.stack([cells, self.tri_ids[: start[-1]].astype(np.int64)], axis=1)
        return np.unique(p, axis=0)

    def memory_bytes(self) -> int:
        """Bytes of the arrays the traversal reads and the build keeps: the leaf level (cell
        offsets and counts, references, per-top-cell resolution and first leaf), the top level's
        cell lists and occupancy (capacity of the references, not just what is used)."""
        return int(self.cell_start.nbytes + self.tri_ids.nbytes + self.cell_count.nbytes + self.macro_full.nbytes
                   + self.leaf_res.nbytes + self.leaf_first.nbytes + self.top_start.nbytes + self.top_ids.nbytes)
