"""``counting``: lock-free two-pass compact grid, beyond the seed.

Lagae & Dutré, "Compact, Fast and Robust Grids for Ray Tracing", EGSR 2008: count the
references of every cell, prefix-sum the counts into offsets, then scatter each reference into
its slot.  Parallel here the way the seed's sort-last strategies split work (Ize et al. 2006):
thread t takes the t-th contiguous block of triangles and both passes write the one shared grid,
the count pass with atomic increments and the scatter with an atomic decrement whose old value
is the slot.  The prefix sum runs in parallel (per-thread block sums, then per-block scans).
Both passes read the triangles' cell ranges from a parallel pre-pass (:func:`shared.cell_ranges`).
Cell lists come out in no particular order.
"""

import numpy as np
from numba import njit, prange

from ..atomics import atomic_add
from ..common import cell_overlaps
from ..registry import register
from .base import Strategy, timed
from .shared import parallel_scan, part, ranges


@njit(cache=True, parallel=True)
def count_atomic(tris, rng, lo, cell, dims, exact, n_threads, count):
    """Atomic count[c] += 1 per reference; thread t counts its block of triangles.
    rng (F, 6) int32 cell ranges (shared.cell_ranges); count (C,) int32, all zero on entry."""
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for t in prange(n_threads):
        for f in range(part(F, t, n_threads), part(F, t + 1, n_threads)):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        atomic_add(count, base + i, np.int32(1))


@njit(cache=True, parallel=True)
def scatter_atomic(tris, rng, lo, cell, dims, exact, n_threads, start, tri_ids):
    """Slot = atomic pre-decrement of start[c]; start (C+1,) int32 holds inclusive ends on entry
    and the CSR starts on exit.  tri_ids (R,) int32."""
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for t in prange(n_threads):
        for f in range(part(F, t, n_threads), part(F, t + 1, n_threads)):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        p = atomic_add(start, base + i, np.int32(-1)) - 1
                        tri_ids[p] = f


@register
class Counting(Strategy):
    """Atomic count -> parallel prefix sum -> atomic scatter into one shared grid."""

    name = "counting"

    def insert(self, tris, spec, bufs, threads, exact, times):
        count = bufs.count[0]
        start = bufs.start[0]
        rng = ranges(tris, spec, bufs, threads, times)
        with timed(times, "count_ms"):
            count_atomic(tris, rng, spec.lo, spec.cell, spec.dims, exact, threads, count)
        with timed(times, "scan_ms"):
            refs = parallel_scan(count, start, threads)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_atomic(tris, rng, spec.lo, spec.cell, spec.dims, exact, threads, start, tri_ids)
        return refs
