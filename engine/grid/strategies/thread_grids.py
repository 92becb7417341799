"""Sort-last with one grid per thread: ``thread_grids_merge`` and ``thread_grids``.

Ize, Wald, Robertson, Parker, RT 2006, "Sort-last: each thread has a copy of its own grid":
thread t inserts the t-th contiguous block of triangles into its own grid, with no
synchronization.  Then either

* ``thread_grids_merge``: "merge grids after triangle insertion": "high memory bandwidth: look
  at all cells in all grids, copy triangles into main grid".  The merge runs in parallel over
  contiguous blocks of cells: sum the per-thread counts, prefix-sum them, copy each cell's lists
  from every thread grid (thread 0 first, so lists stay in ascending triangle order).  The
  per-thread grids are scratch arrays zeroed by the merge as it reads them, so they are clean
  for the next frame (this is where the "must clear all grids" cost of Ize et al. 2006 lands);
* ``thread_grids``: "don't merge and instead check grids during traversal": the per-thread
  grids are the grid's layers (``layered = True``, ``cell_start`` (T, C+1)); the shared clear
  and macro-cell stages run over all T layers ("must perform grid clear and macro cell build for
  all grids: no longer scalable") and the ray caster visits every layer of a cell.

A per-thread grid is compact: thread t counts its references into its own count row, scans that
row from its offset in the shared reference buffer, and scatters backwards, all in one
private pass; layer t's references follow layer t-1's in the reference buffer.  Cell ranges come
from a parallel pre-pass (:func:`shared.cell_ranges`).  Each thread is the first to write its
own count row (the arrays are calloc'd), which places those pages on its NUMA node.
"""

import numpy as np
from numba import njit, prange

from ..common import cell_overlaps
from .base import Strategy, timed
from ..buffers import scratch, scratch_done, zero_scratch
from .shared import check_total, exclusive, part, ranges


@njit(cache=True, parallel=True)
def count_layers(tris, rng, box, exact, n_threads, count, tot):
    """Thread t counts its triangle block into its own row: count (T, C) int32 zero on entry;
    tot (T,) int64 receives each thread's reference total; box the grid (layout.GridBox)."""
    lo, cell, dims = box.lo, box.cell, box.dims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for t in prange(n_threads):
        s = 0
        row = count[t]
        for f in range(part(F, t, n_threads), part(F, t + 1, n_threads)):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        row[base + i] += 1
                        s += 1
        tot[t] = s


@njit(cache=True, parallel=True)
def scan_scatter_layers(tris, rng, box, exact, n_threads, base_t, count, start, tri_ids):
    """Thread t scans row t of count from base_t[t] and scatters its triangle block backwards.

    count (T, C) int32, start (T, C+1) int32 (CSR starts on exit, start[t, C] = end of layer t,
    offsets global into tri_ids (R,) int32), base_t (T,) int64 exclusive layer offsets.
    """
    lo, cell, dims = box.lo, box.cell, box.dims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    C = count.shape[1]
    for t in prange(n_threads):
        crow = count[t]
        srow = start[t]
        s = base_t[t]
        for c in range(C):
            s += crow[c]
            srow[c] = s
        srow[C] = s
        for f in range(part(F, t + 1, n_threads) - 1, part(F, t, n_threads) - 1, -1):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        c = base + i
                        p = srow[c] - 1
                        srow[c] = p
                        tri_ids[p] = f


@njit(cache=True, parallel=True)
def merge_counts(tcount, n_threads, count, sums):
    """count[c] = sum over threads of tcount[:, c], each thread a block of cells; sums (T,)
    int64 receives the block totals.  tcount (L, C) int32, count (C,) int32."""
    L, C = tcount.shape
    for t in prange(n_threads):
        s = 0
        for c in range(part(C, t, n_threads), part(C, t + 1, n_threads)):
            n = 0
            for l in range(L):
                n += tcount[l, c]
            count[c] = n
            s += n
        sums[t] = s


@njit(cache=True, parallel=True)
def merge_copy(tcount, tstart, trefs, n_threads, base_t, start, tri_ids):
    """Copy every cell's lists from all thread grids (layer order) into the merged grid.

    Block t of cells starts at base_t[t] in tri_ids; start (C+1,) int32 receives CSR starts
    (start[C] is set by the caller).  Zeroes tcount as it goes (the thread grids' clear).
    """
    L, C = tcount.shape
    for t in prange(n_threads):
        p = base_t[t]
        for c in range(part(C, t, n_threads), part(C, t + 1, n_threads)):
            start[c] = p
            for l in range(L):
                if tcount[l, c] != 0:
                    for r in range(tstart[l, c], tstart[l, c + 1]):
                        tri_ids[p] = trefs[r]
                        p += 1
                    tcount[l, c] = 0


def _insert_layers(tris, spec, bufs, count, start, threads, exact, times, refs_for):
    """Per-thread grids into count (T, C) / start (T, C+1); refs_for(n) gives the (n,) reference
    buffer.  Returns (total references, that buffer)."""
    tot = np.zeros(threads, np.int64)
    rng = ranges(tris, spec, bufs, threads, times)
    with timed(times, "count_ms"):
        count_layers(tris, rng, spec.box, exact, threads, count, tot)
    base_t, refs = exclusive(tot)
    check_total(refs)
    tri_ids = refs_for(refs)
    with timed(times, "scatter_ms"):
        scan_scatter_layers(tris, rng, spec.box, exact, threads, base_t, count, start, tri_ids)
    return refs, tri_ids


class ThreadGridsMerge(Strategy):
    """One private grid per thread, merged into one grid in parallel after insertion."""

    name = "thread_grids_merge"

    def insert(self, tris, spec, bufs, threads, exact, times):
        C = spec.n_cells
        layer_bytes = threads * (2 * C + 1) * 4
        bufs.check_budget(layer_bytes, f"{threads} per-thread grids of {C} cells")
        tcount = zero_scratch(bufs, "tg_count", threads * C, np.int32).reshape(threads, C)
        tstart = scratch(bufs, "tg_start", threads * (C + 1), np.int32).reshape(threads, C + 1)

        def per_thread_refs(n):
            bufs.check_budget(layer_bytes + 8 * n, f"{n} references, held twice while the per-thread grids merge")
            return scratch(bufs, "tg_refs", n, np.int32)

        refs, trefs = _insert_layers(tris, spec, bufs, tcount, tstart, threads, exact, times, per_thread_refs)
        count = bufs.count[0]
        start = bufs.start[0]
        with timed(times, "merge_ms"):
            sums = np.empty(threads, np.int64)
            merge_counts(tcount, threads, count, sums)
            base_t, total = exclusive(sums)
            tri_ids = bufs.refs(refs)
            merge_copy(tcount, tstart, trefs, threads, base_t, start, tri_ids)
            start[C] = total
        scratch_done(bufs, "tg_count")
        return refs


class ThreadGrids(Strategy):
    """One private grid per thread, kept as the grid's layers and all traversed."""

    name = "thread_grids"
    layered = True

    def insert(self, tris, spec, bufs, threads, exact, times):
        refs, _ = _insert_layers(tris, spec, bufs, bufs.count, bufs.start, threads, exact, times, bufs.refs)
        return refs
