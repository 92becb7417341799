"""``counting``: lock-free two-pass compact grid, beyond Ize et al. 2006.

Lagae & Dutré, "Compact, Fast and Robust Grids for Ray Tracing", EGSR 2008: count the
references of every cell, prefix-sum the counts into offsets, then scatter each reference into
its slot.  Parallel here the way the sort-last strategies of Ize et al. 2006 split work:
thread t takes the t-th contiguous block of triangles and both passes write the one shared grid.

The count pass increments cell counts with atomic adds and keeps what each add returns, the
reference's rank among its cell's references (the usual GPU formulation of this build).  The
scatter then needs no atomics at all: slot = start[cell] + rank, with ``start`` only read.  The
ranks take 4 bytes per reference; thread t writes its ranks from an offset given by the cell
volumes of the triangle ranges before it (:func:`shared.range_volumes`, exact for bbox insertion
and an upper bound for exact insertion, whose rejected cells take no rank).  The prefix sum runs
in parallel (per-thread block sums, then per-block scans).  Both passes read the triangles' cell
ranges from the parallel pre-pass (:func:`shared.cell_ranges`).  Cell lists come out in no
particular order.
"""

import numpy as np
from numba import njit, prange

from ...compiles import inner
from ..atomics import atomic_add
from ..buffers import scratch
from ..common import cell_overlaps
from .base import Strategy, timed
from .shared import check_total, exclusive, parallel_scan_exclusive, part, range_volumes, ranges


@inner(cache=True, _nrt=False)
def _count_block(tris, rng, f0, box, exact, count, ranks):
    """Atomic count[c] += 1 for the references of triangles f0.. (rng: their rows), storing each
    add's old value in ranks (a slice starting at this block's offset); returns ranks used."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    p = 0
    for r in range(rng.shape[0]):
        i0, j0, k0, i1, j1, k1 = rng[r, 0], rng[r, 1], rng[r, 2], rng[r, 3], rng[r, 4], rng[r, 5]
        for k in range(k0, k1 + 1):
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact and not cell_overlaps(tris, f0 + r, i, j, k, lo, cell):
                        continue
                    ranks[p] = atomic_add(count, base + i, np.int32(1))
                    p += 1
    return p


@njit(cache=True, parallel=True)
def count_atomic(tris, rng, box, exact, n_threads, rank_base, count, ranks):
    """Thread t counts its block of triangles into count (C,) int32 (all zero on entry) with
    atomic adds; its ranks go to ranks[rank_base[t]:] (ranks (Rb,) int32, rank_base (T,) int64)."""
    F = tris.shape[0]
    for t in prange(n_threads):
        a = part(F, t, n_threads)
        b = part(F, t + 1, n_threads)
        _count_block(tris, rng[a:b], a, box, exact, count, ranks[rank_base[t]:])


@inner(cache=True, _nrt=False)
def _scatter_block(tris, rng, f0, box, exact, start, ranks, tri_ids):
    """tri_ids[start[c] + rank] = f for the references of triangles f0.., walked in the count
    pass's order."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    p = 0
    for r in range(rng.shape[0]):
        i0, j0, k0, i1, j1, k1 = rng[r, 0], rng[r, 1], rng[r, 2], rng[r, 3], rng[r, 4], rng[r, 5]
        f = f0 + r
        for k in range(k0, k1 + 1):
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                        continue
                    tri_ids[start[base + i] + ranks[p]] = f
                    p += 1


@njit(cache=True, parallel=True)
def scatter_ranked(tris, rng, box, exact, n_threads, rank_base, start, ranks, tri_ids):
    """Every reference to its slot start[c] + rank, no atomics; start (C+1,) int32 CSR offsets
    (read only), tri_ids (R,) int32."""
    F = tris.shape[0]
    for t in prange(n_threads):
        a = part(F, t, n_threads)
        b = part(F, t + 1, n_threads)
        _scatter_block(tris, rng[a:b], a, box, exact, start, ranks[rank_base[t]:], tri_ids)


class Counting(Strategy):
    """Atomic count (keeping ranks) -> parallel prefix sum -> atomic-free scatter."""

    name = "counting"

    def insert(self, tris, spec, bufs, threads, exact, times):
        count = bufs.count[0]
        start = bufs.start[0]
        rng = ranges(tris, spec, bufs, threads, times)
        with timed(times, "count_ms"):
            vol = np.empty(threads, np.int64)
            range_volumes(rng, threads, vol)
            rank_base, bound = exclusive(vol)
            check_total(bound)
            bufs.check_budget(4 * bound, f"ranks of up to {bound} references")
            ranks = scratch(bufs, "ranks", max(bound, 1), np.int32)
            count_atomic(tris, rng, spec.box, exact, threads, rank_base, count, ranks)
        with timed(times, "scan_ms"):
            refs = parallel_scan_exclusive(count, start, threads)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_ranked(tris, rng, spec.box, exact, threads, rank_base, start, ranks, tri_ids)
        return refs
