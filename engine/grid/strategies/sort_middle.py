"""``sort_middle``: the winner of Ize et al. 2006.

Ize, Wald, Robertson, Parker, RT 2006, "Sort-middle": each thread takes a subset of the
triangles and "performs a coarse bucket sort on its triangles", using ``z % num_threads`` where
z is the major index of each overlapped cell ("triangle might exist in multiple buckets"); then
"each thread gets a group of similar buckets" and "inserts into specific locations of grid: no
write conflicts between threads".

Here: thread t takes the t-th contiguous block of triangles, computes their cell ranges
(16 at a time, vectorized) and sorts them into T private buckets in the same pass (bucket j of
thread t lives in row j of a (T, F) buffer, in thread t's block of columns, so no thread waits
for another's counts).  Thread j then owns the cell layers with
``z % T == j`` and inserts bucket j of every thread, in thread order, into them (count, prefix
sum over all cells in parallel, scatter backwards), touching only its own layers.  No locks, no
atomics.  Triangles are visited in ascending order, so cell lists come out ascending, as
serial's.  The bucket buffer holds T x F int32 (checked against the build's max_bytes).
"""

import numpy as np
from numba import njit, prange

from ...compiles import inner
from ..buffers import scratch
from ..common import RANGE_LANES, cell_overlaps, cell_ranges_into
from .base import Strategy, timed
from .shared import parallel_scan, part


@inner(cache=True, _nrt=False)
def _bucket_rows(rng, f0, T, zmod, flat_lists, pos):
    """Bucket the triangles f0.. (rng: their rows): triangle f goes to flat_lists[pos[j]] for
    every bucket j it belongs to; pos (T,) int64 holds each bucket's next slot (flat index into
    the (T, F) buffer) and moves on by one per entry.

    Branch-free: every bucket j gets a store and its slot moves on only when the range's layers
    k0..k1 include one with z % T == j, so a mix of one- and two-layer triangles costs no
    mispredictions.  The store lands inside the thread's block of the row (entries <= triangles
    so far).  zmod[z] = z % T: an integer division per triangle would cost more than the rest."""
    for r in range(rng.shape[0]):
        k0 = rng[r, 2]
        span = rng[r, 5] - k0 + 1  # 0 for an empty range
        km = zmod[k0]
        f = np.int32(f0 + r)
        for j in range(T):
            d = j - km
            d = d + T if d < 0 else d
            p = pos[j]
            flat_lists[p] = f
            pos[j] = p + (1 if d < span else 0)


@inner(cache=True)
def _ranges_buckets_block(flat, f0, f1, box, T, zmod, rng, lists, lcount, t):
    """Cell ranges of triangles f0..f1-1 (flat: all coordinates) into rng, and their buckets,
    16 triangles at a time so the bucket pass reads ranges still in L1; lcount[:, t] = sizes."""
    F = lists.shape[1]
    pos = np.empty(T, np.int64)
    for j in range(T):
        pos[j] = j * F + f0
    flat_lists = lists.reshape(lists.size)
    out = rng.reshape(rng.size)
    B = RANGE_LANES
    for g0 in range(f0, f1, B):
        g1 = min(g0 + B, f1)
        cell_ranges_into(flat[9 * g0:9 * g1], box, out[6 * g0:6 * g1])
        _bucket_rows(rng[g0:g1], g0, T, zmod, flat_lists, pos)
    for j in range(T):
        lcount[j, t] = pos[j] - (j * F + f0)


@njit(cache=True, parallel=True)
def ranges_and_buckets(tris, box, n_threads, zmod, rng, lists, lcount):
    """Thread t computes the cell ranges of its block of triangles (into rng (F, 6) int32) and
    sorts the block into T private buckets in the same pass: bucket j gets every triangle that
    overlaps some cell layer z with z % T == j.

    lists (T, F) int32: thread t's bucket j is lists[j, part(F, t, T) : part(F, t, T) +
    lcount[j, t]] (a triangle enters a bucket at most once, so each thread's block of a row is
    room enough); lcount (T, T) int64.
    """
    F = tris.shape[0]
    T = n_threads
    flat = tris.reshape(tris.size)
    for t in prange(T):
        _ranges_buckets_block(flat, part(F, t, T), part(F, t + 1, T), box, T, zmod, rng, lists, lcount, np.int64(t))


@inner(cache=True, _nrt=False)
def _count_bucket(tris, rng, box, exact, T, zmod, jt, bucket, count):
    """count[c] += 1 for the references of the triangles in bucket (a slice of lists) that lie
    in the layers z % T == jt."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for r in range(bucket.shape[0]):
        f = bucket[r]
        i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
        d = jt - zmod[k0]
        k = k0 + (d + T if d < 0 else d)  # first owned layer; a while loop: range(.., T) divides
        while k <= k1:
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                        continue
                    count[base + i] += 1
            k += T


@njit(cache=True, parallel=True)
def count_owned(tris, rng, box, exact, n_threads, zmod, lists, lcount, count):
    """Thread j counts the references of bucket j (of every thread, in thread order) into the
    layers z % T == j.  count (C,) int32 zero on entry."""
    T = n_threads
    F = rng.shape[0]
    for jt in prange(T):
        for t in range(T):
            a = part(F, t, T)
            _count_bucket(tris, rng, box, exact, T, zmod, np.int64(jt), lists[jt, a:a + lcount[jt, t]], count)


@inner(cache=True, _nrt=False)
def _scatter_bucket(tris, rng, box, exact, T, zmod, jt, bucket, start, tri_ids):
    """Scatter bucket (a slice of lists) backwards into the layers z % T == jt by pre-decrement."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for r in range(bucket.shape[0] - 1, -1, -1):
        f = bucket[r]
        i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
        d = jt - zmod[k0]
        k = k0 + (d + T if d < 0 else d)
        while k <= k1:
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                        continue
                    c = base + i
                    p = start[c] - 1
                    start[c] = p
                    tri_ids[p] = f
            k += T


@njit(cache=True, parallel=True)
def scatter_owned(tris, rng, box, exact, n_threads, zmod, lists, lcount, start, tri_ids):
    """Thread j scatters bucket j backwards (last thread's part first) into its layers; start
    (C+1,) int32 inclusive ends on entry, CSR starts on exit; tri_ids (R,) int32."""
    T = n_threads
    F = rng.shape[0]
    for jt in prange(T):
        for t in range(T - 1, -1, -1):
            a = part(F, t, T)
            _scatter_bucket(tris, rng, box, exact, T, zmod, np.int64(jt), lists[jt, a:a + lcount[jt, t]], start, tri_ids)


class SortMiddle(Strategy):
    """Bucket-sort triangle blocks by z % T, then thread j fills the layers z % T == j."""

    name = "sort_middle"
    counters = ("bucket_entries",)

    def insert(self, tris, spec, bufs, threads, exact, times):
        T = threads
        F = tris.shape[0]
        count = bufs.count[0]
        start = bufs.start[0]
        bufs.check_budget(4 * T * F, f"{T} buckets of up to {F} triangles")
        with timed(times, "bucket_ms"):
            rng = scratch(bufs, "cell_ranges", 6 * F, np.int32).reshape(F, 6)
            lists = scratch(bufs, "sm_buckets", T * F, np.int32).reshape(T, F)
            lcount = np.empty((T, T), np.int64)
            zmod = np.arange(spec.dims[2], dtype=np.int64) % T
            ranges_and_buckets(tris, spec.box, T, zmod, rng, lists, lcount)
        times["bucket_entries"] = int(lcount.sum())  # a count riding along with the stage times
        with timed(times, "count_ms"):
            count_owned(tris, rng, spec.box, exact, T, zmod, lists, lcount, count)
        with timed(times, "scan_ms"):
            refs = parallel_scan(count, start, T)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_owned(tris, rng, spec.box, exact, T, zmod, lists, lcount, start, tri_ids)
        return refs
