"""``sort_middle``: the seed's winner.

Ize, Wald, Robertson, Parker, RT 2006, "Sort-middle": each thread takes a subset of the
triangles and "performs a coarse bucket sort on its triangles", using ``z % num_threads`` where
z is the major index of each overlapped cell ("triangle might exist in multiple buckets"); then
"each thread gets a group of similar buckets" and "inserts into specific locations of grid: no
write conflicts between threads".

Here: the triangles' cell ranges come from the shared parallel pass (:func:`shared.ranges`);
thread t takes the t-th contiguous block of triangles and sorts it into T private buckets in
one pass (bucket j of thread t lives in row j of a (T, F) buffer, in thread t's block of
columns, so no thread waits for another's counts).  Thread j then owns the cell layers with
``z % T == j`` and inserts bucket j of every thread, in thread order, into them (count, prefix
sum over all cells in parallel, scatter backwards), touching only its own layers.  No locks, no
atomics.  Triangles are visited in ascending order, so cell lists come out ascending, as
serial's.  The bucket buffer holds T x F int32 (checked against the build's max_bytes).
"""

import numpy as np
from numba import njit, prange

from ..common import cell_overlaps
from ..registry import register
from .base import Strategy, timed
from .shared import parallel_scan, part, ranges, scratch


@njit(cache=True, parallel=True)
def bucket_sort(rng, n_threads, lists, lcount):
    """Thread t sorts its block of triangles into T private buckets in one pass: bucket j gets
    every triangle that overlaps some cell layer z with z % T == j.

    rng (F, 6) int32 cell ranges; lists (T, F) int32: thread t's bucket j is
    lists[j, part(F, t, T) : part(F, t, T) + lcount[j, t]] (a triangle enters a bucket at most
    once, so each thread's block of a row is room enough); lcount (T, T) int64.
    """
    F = rng.shape[0]
    T = n_threads
    for t in prange(T):
        a = part(F, t, T)
        b = part(F, t + 1, T)
        n = np.zeros(T, np.int64)  # private counts: no false sharing on lcount
        for f in range(a, b):
            k0 = rng[f, 2]
            k1 = rng[f, 5]
            if k1 - k0 + 1 >= T:
                for j in range(T):
                    lists[j, a + n[j]] = f
                    n[j] += 1
            else:
                j = k0 % T
                for k in range(k0, k1 + 1):
                    lists[j, a + n[j]] = f
                    n[j] += 1
                    j += 1
                    if j == T:
                        j = 0
        for j in range(T):
            lcount[j, t] = n[j]


@njit(cache=True, parallel=True)
def count_owned(tris, rng, lo, cell, dims, exact, n_threads, lists, lcount, count):
    """Thread j counts the references of bucket j (of every thread, in thread order) into the
    layers z % T == j.  count (C,) int32 zero on entry."""
    T = n_threads
    F = rng.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for jt in prange(T):
        for t in range(T):
            a = part(F, t, T)
            for r in range(a, a + lcount[jt, t]):
                f = lists[jt, r]
                i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
                for k in range(k0 + (jt - k0) % T, k1 + 1, T):
                    for j in range(j0, j1 + 1):
                        base = k * nxy + j * nx
                        for i in range(i0, i1 + 1):
                            if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                                continue
                            count[base + i] += 1


@njit(cache=True, parallel=True)
def scatter_owned(tris, rng, lo, cell, dims, exact, n_threads, lists, lcount, start, tri_ids):
    """Thread j scatters bucket j backwards (last thread's part first) into its layers; start
    (C+1,) int32 inclusive ends on entry, CSR starts on exit; tri_ids (R,) int32."""
    T = n_threads
    F = rng.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for jt in prange(T):
        for t in range(T - 1, -1, -1):
            a = part(F, t, T)
            for r in range(a + lcount[jt, t] - 1, a - 1, -1):
                f = lists[jt, r]
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
        F = tris.shape[0]
        count = bufs.count[0]
        start = bufs.start[0]
        bufs.check_budget(4 * T * F, f"{T} buckets of up to {F} triangles")
        rng = ranges(tris, spec, bufs, T, times)
        with timed(times, "bucket_ms"):
            lists = scratch(bufs, "sm_buckets", T * F, np.int32).reshape(T, F)
            lcount = np.empty((T, T), np.int64)
            bucket_sort(rng, T, lists, lcount)
        with timed(times, "count_ms"):
            count_owned(tris, rng, spec.lo, spec.cell, spec.dims, exact, T, lists, lcount, count)
        with timed(times, "scan_ms"):
            refs = parallel_scan(count, start, T)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_owned(tris, rng, spec.lo, spec.cell, spec.dims, exact, T, lists, lcount, start, tri_ids)
        return refs
