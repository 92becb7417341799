"""``sort_middle``: the seed's winner.

Ize, Wald, Robertson, Parker, RT 2006, "Sort-middle": each thread takes a subset of the
triangles and "performs a coarse bucket sort on its triangles", using ``z % num_threads`` where
z is the major index of each overlapped cell ("triangle might exist in multiple buckets"); then
"each thread gets a group of similar buckets" and "inserts into specific locations of grid: no
write conflicts between threads".

Here: thread t takes the t-th contiguous block of triangles and sorts them into T buckets in
two private passes (count, then fill; the count pass also stores each triangle's cell range for
the later passes) into one shared bucket buffer laid out bucket-major, so
bucket j of every thread forms one contiguous run.  Thread j then owns the cell layers with
``z % T == j`` and inserts the triangles of run j into them (count, prefix sum over all cells in
parallel, scatter backwards), touching only its own layers.  No locks, no atomics.  Within a run
the triangles are in ascending order, so cell lists come out ascending, as serial's.
"""

import numpy as np
from numba import njit, prange

from ..common import cell_overlaps, tri_cell_range
from ..registry import register
from .base import Strategy, timed
from .shared import check_total, parallel_scan, part, scratch


@njit(cache=True, parallel=True)
def bucket_count(tris, lo, inv_cell, dims, n_threads, bcount, rng):
    """bcount[j, t] = triangles of thread t's block that overlap some cell layer z with
    z % T == j.  bcount (T, T) int64.  rng (F, 6) int32 receives every triangle's cell range
    (i0, j0, k0, i1, j1, k1), read by the later passes instead of recomputing it."""
    F = tris.shape[0]
    T = n_threads
    for t in prange(T):
        loc = np.zeros(T, np.int64)
        for f in range(part(F, t, T), part(F, t + 1, T)):
            i0, j0, k0, i1, j1, k1 = tri_cell_range(tris, f, lo, inv_cell, dims)
            rng[f, 0] = i0
            rng[f, 1] = j0
            rng[f, 2] = k0
            rng[f, 3] = i1
            rng[f, 4] = j1
            rng[f, 5] = k1
            if k1 - k0 + 1 >= T:
                for j in range(T):
                    loc[j] += 1
            else:
                j = k0 % T
                for k in range(k0, k1 + 1):
                    loc[j] += 1
                    j += 1
                    if j == T:
                        j = 0
        for j in range(T):
            bcount[j, t] = loc[j]


@njit(cache=True, parallel=True)
def bucket_fill(rng, n_threads, boff, buckets):
    """Thread t writes its triangles into its slots of every bucket; boff (T, T) int64 holds
    the first slot of (bucket j, thread t); buckets (B,) int32; rng (F, 6) int32 cell ranges."""
    F = rng.shape[0]
    T = n_threads
    for t in prange(T):
        cur = np.empty(T, np.int64)
        for j in range(T):
            cur[j] = boff[j, t]
        for f in range(part(F, t, T), part(F, t + 1, T)):
            k0 = rng[f, 2]
            k1 = rng[f, 5]
            if k1 - k0 + 1 >= T:
                for j in range(T):
                    buckets[cur[j]] = f
                    cur[j] += 1
            else:
                j = k0 % T
                for k in range(k0, k1 + 1):
                    buckets[cur[j]] = f
                    cur[j] += 1
                    j += 1
                    if j == T:
                        j = 0


@njit(cache=True, parallel=True)
def count_owned(tris, rng, lo, cell, dims, exact, n_threads, bstart, buckets, count):
    """Thread j counts the references of run j's triangles into the layers z % T == j.
    bstart (T+1,) int64 run bounds in buckets (B,) int32; count (C,) int32 zero on entry."""
    T = n_threads
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for jt in prange(T):
        for r in range(bstart[jt], bstart[jt + 1]):
            f = buckets[r]
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0 + (jt - k0) % T, k1 + 1, T):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        count[base + i] += 1


@njit(cache=True, parallel=True)
def scatter_owned(tris, rng, lo, cell, dims, exact, n_threads, bstart, buckets, start, tri_ids):
    """Thread j scatters run j backwards into its layers; start (C+1,) int32 inclusive ends on
    entry, CSR starts on exit; tri_ids (R,) int32."""
    T = n_threads
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for jt in prange(T):
        for r in range(bstart[jt + 1] - 1, bstart[jt] - 1, -1):
            f = buckets[r]
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0 + (jt - k0) % T, k1 + 1, T):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        c = base + i
                        p = start[c] - 1
                        start[c] = p
                        tri_ids[p] = f


@register
class SortMiddle(Strategy):
    """Bucket-sort triangle blocks by z % T, then thread j fills the layers z % T == j."""

    name = "sort_middle"

    def insert(self, tris, spec, bufs, threads, exact, times):
        T = threads
        count = bufs.count[0]
        start = bufs.start[0]
        with timed(times, "bucket_ms"):
            bcount = np.empty((T, T), np.int64)
            F = tris.shape[0]
            rng = scratch(bufs, "cell_ranges", 6 * F, np.int32).reshape(F, 6)
            bucket_count(tris, spec.lo, spec.inv_cell, spec.dims, T, bcount, rng)
            flat = bcount.ravel()
            boff = np.zeros(T * T + 1, np.int64)
            np.cumsum(flat, out=boff[1:])
            n_entries = int(boff[-1])
            check_total(n_entries)
            buckets = scratch(bufs, "sm_buckets", n_entries, np.int32)
            bucket_fill(rng, T, boff[:-1].reshape(T, T), buckets)
            bstart = boff[:: T].copy()  # run j = buckets (j, 0) .. (j, T-1)
        with timed(times, "count_ms"):
            count_owned(tris, rng, spec.lo, spec.cell, spec.dims, exact, T, bstart, buckets, count)
        with timed(times, "scan_ms"):
            refs = parallel_scan(count, start, T)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_owned(tris, rng, spec.lo, spec.cell, spec.dims, exact, T, bstart, buckets, start, tri_ids)
        return refs
