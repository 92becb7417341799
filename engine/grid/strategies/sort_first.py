"""``sort_first``: each thread owns a part of the grid and looks at every triangle.

Ize, Wald, Robertson, Parker, RT 2006, "Sort-first": "each thread is given a subset of the grid
which it must insert triangles into"; no synchronization on cells or triangles, but "each
thread must look at ALL triangles", so the build stays O(triangles) per thread.  The subsets
here are z-slabs: thread t owns the cell layers ``t*nz//T .. (t+1)*nz//T - 1``, which are also
one contiguous range of linear cell indices (z is the major index), so each thread counts, scans
and scatters its own slab with no shared writes.  A parallel pre-pass stores every triangle's
cell range (six int32, :func:`shared.cell_ranges`), so the per-thread look at all triangles
reads those instead of recomputing them.
Threads beyond nz get empty slabs.  Cell lists come out in ascending triangle order, as serial's.
"""

import numpy as np
from numba import njit, prange

from ..common import cell_overlaps, scan_into
from .base import Strategy, timed
from .shared import cell_ranges, check_total, exclusive, part, ranges


@njit(cache=True, parallel=True)
def count_slabs(tris, rng, box, exact, n_threads, count, tot):
    """Thread t counts the references of its z-slab over all triangles.  rng (F, 6) int32
    cell ranges; box the grid (layout.GridBox); count (C,) int32 zero on entry; tot (T,) int64
    receives the references per slab."""
    lo, cell, dims = box.lo, box.cell, box.dims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    nz = dims[2]
    for t in prange(n_threads):
        z0 = part(nz, t, n_threads)
        z1 = part(nz, t + 1, n_threads) - 1
        s = 0
        if z0 <= z1:
            for f in range(F):
                if rng[f, 5] < z0 or rng[f, 2] > z1:
                    continue
                i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
                for k in range(max(k0, z0), min(k1, z1) + 1):
                    for j in range(j0, j1 + 1):
                        base = k * nxy + j * nx
                        for i in range(i0, i1 + 1):
                            if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                                continue
                            count[base + i] += 1
                            s += 1
        tot[t] = s


@njit(cache=True, parallel=True)
def scan_scatter_slabs(tris, rng, box, exact, n_threads, base_t, count, start, tri_ids):
    """Thread t scans its slab's counts from offset base_t[t] (inclusive ends), then scatters
    every triangle backwards into its slab, leaving CSR starts and ascending cell lists.
    start (C+1,) int32 (start[C] is set by the caller); tri_ids (R,) int32."""
    lo, cell, dims = box.lo, box.cell, box.dims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    nz = dims[2]
    for t in prange(n_threads):
        z0 = part(nz, t, n_threads)
        z1 = part(nz, t + 1, n_threads) - 1
        if z0 > z1:
            continue
        a = z0 * nxy
        b = (z1 + 1) * nxy
        scan_into(count[a:b], base_t[t], start[a:b])  # slices: the loop starts at 0 and vectorizes
        for f in range(F - 1, -1, -1):
            if rng[f, 5] < z0 or rng[f, 2] > z1:
                continue
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(max(k0, z0), min(k1, z1) + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        c = base + i
                        p = start[c] - 1
                        start[c] = p
                        tri_ids[p] = f


class SortFirst(Strategy):
    """z-slab per thread, every thread reads all triangles; no synchronization."""

    name = "sort_first"
    parallel_kernels = (cell_ranges, count_slabs, scan_scatter_slabs)

    def insert(self, tris, spec, bufs, threads, exact, times):
        count = bufs.count[0]
        start = bufs.start[0]
        tot = np.zeros(threads, np.int64)
        rng = ranges(tris, spec, bufs, threads, times)
        with timed(times, "count_ms"):
            count_slabs(tris, rng, spec.box, exact, threads, count, tot)
        base_t, refs = exclusive(tot)
        check_total(refs)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scan_scatter_slabs(tris, rng, spec.box, exact, threads, base_t, count, start, tri_ids)
            start[spec.n_cells] = refs
        return refs
