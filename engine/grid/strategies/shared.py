"""Pieces the parallel strategies share: the parallel prefix sum over the cell counts and the
per-build scratch arrays some strategies keep next to the grid buffers.

Kernels follow the engine's rule for thread counts: ``for t in prange(n_threads)`` with each
iteration doing thread ``t``'s share, so the logical thread count is exact even with more
threads than cores.  Scratch arrays are allocated with ``np.zeros`` (calloc: pages are mapped on
first write), so each page is first touched by the thread that fills it, which is what a NUMA
machine needs to place it on that thread's node (Ize et al. 2006, "Targeting NUMA").
"""

import numpy as np
from numba import njit, prange

from ...compiles import inner
from ...errors import InputError
from ..buffers import scratch
from ..common import cell_ranges_into, scan_into, sum_of
from .base import timed

INT32_MAX = np.iinfo(np.int32).max


@njit(cache=True)
def part(n, t, T):
    """First index of part t of n items split into T contiguous parts (part t is
    ``part(n, t, T) .. part(n, t + 1, T) - 1``)."""
    return t * n // T


# ---------------------------------------------------------------------------------------------
# triangle cell ranges, computed once per build


@njit(cache=True, parallel=True)
def cell_ranges(tris, box, n_threads, rng):
    """rng[f] = (i0, j0, k0, i1, j1, k1), triangle f's inclusive cell range (common._ranges_block).

    tris (F, 3, 3) float32 C-contiguous; box the grid (layout.GridBox); rng (F, 6) int32
    C-contiguous.  Thread t does its
    block of triangles with the vectorized common.cell_ranges_into.  The count and scatter
    passes read these 24 bytes instead of recomputing six float64 floors from the 36 bytes of
    vertices each time.
    """
    F = tris.shape[0]
    flat = tris.reshape(tris.size)
    out = rng.reshape(rng.size)
    for t in prange(n_threads):
        a = part(F, t, n_threads)
        b = part(F, t + 1, n_threads)
        cell_ranges_into(flat[9 * a:9 * b], box, out[6 * a:6 * b])


def ranges(tris, spec, bufs, n_threads, times):
    """(F, 6) int32 cell ranges of every triangle in a reused scratch array; times
    ``ranges_ms``."""
    F = tris.shape[0]
    rng = scratch(bufs, "cell_ranges", 6 * F, np.int32).reshape(F, 6)
    with timed(times, "ranges_ms"):
        if n_threads == 1:  # the same pass without the parallel loop (a cold start compiles less)
            cell_ranges_into(tris.reshape(tris.size), spec.box, rng.reshape(rng.size))
        else:
            cell_ranges(tris, spec.box, n_threads, rng)
    return rng


# ---------------------------------------------------------------------------------------------
# parallel prefix sum (per-thread block sums, exclusive scan of the sums, per-block scan)


@njit(cache=True, parallel=True)
def block_sums(count, n_threads, sums):
    """sums[t] = sum of count over thread t's block of cells.  count (C,) int32, sums (T,) int64."""
    C = count.shape[0]
    for t in prange(n_threads):
        sums[t] = sum_of(count[part(C, t, n_threads):part(C, t + 1, n_threads)])


@njit(cache=True, parallel=True)
def block_scan_inclusive(count, base, n_threads, out):
    """out[c] = base[t] + inclusive sum of count over thread t's block up to c.

    count (C,) int32, base (T,) int64 exclusive block offsets, out (C,) int32 (a view of the
    CSR offsets, shifted by one for exclusive starts)."""
    C = count.shape[0]
    for t in prange(n_threads):
        a = part(C, t, n_threads)
        b = part(C, t + 1, n_threads)
        scan_into(count[a:b], base[t], out[a:b])


def check_total(total):
    """The reference total as int; InputError when it does not fit the int32 CSR offsets."""
    total = int(total)
    if total > INT32_MAX:
        raise InputError(
            f"the grid would hold {total} references, more than int32 offsets allow; lower the density "
            f"(lambda) or use exact insertion"
        )
    return total


def exclusive(sums):
    """Exclusive prefix sum of a small (T,) int64 array, plus the total."""
    base = np.zeros(len(sums), np.int64)
    np.cumsum(sums[:-1], out=base[1:])
    return base, int(sums.sum())


def _scan(count, out, n_threads):
    """Inclusive scan of count (C,) int32 into out (C,) int32 (a view into the CSR offsets), in
    parallel: per-thread block sums, then per-block scans from the blocks' offsets.  Two passes
    over the counts instead of one, so one thread runs the one-pass serial scan.  Returns the
    total after checking it fits int32."""
    if n_threads == 1:
        return check_total(scan_into(count, 0, out))
    sums = np.empty(n_threads, np.int64)
    block_sums(count, n_threads, sums)
    base, total = exclusive(sums)
    check_total(total)
    block_scan_inclusive(count, base, n_threads, out)
    return total


def parallel_scan(count, start, n_threads):
    """Inclusive ends for a pre-decrementing scatter: start[c] = count[0] + ... + count[c],
    start[C] = total (start (C + 1,) int32); returns the total."""
    C = count.shape[0]
    total = _scan(count, start[:C], n_threads)
    start[C] = total
    return total


def parallel_scan_exclusive(count, start, n_threads):
    """CSR offsets in one go: start[0] = 0, start[c + 1] = count[0] + ... + count[c] (start
    (C + 1,) int32); returns the total."""
    start[0] = 0
    return _scan(count, start[1:], n_threads)


@inner(cache=True, _nrt=False)
def _volume_sum(rng):
    """Sum over the rows of rng (n, 6) int32 of the cell-range volumes (0 for empty ranges)."""
    s = 0
    for r in range(rng.shape[0]):
        s += (rng[r, 3] - rng[r, 0] + 1) * (rng[r, 4] - rng[r, 1] + 1) * (rng[r, 5] - rng[r, 2] + 1)
    return s


@njit(cache=True, parallel=True)
def range_volumes(rng, n_threads, sums):
    """sums[t] = cells in the ranges of thread t's block of triangles: the references a bbox
    insertion makes and an upper bound for an exact one.  rng (F, 6) int32, sums (T,) int64."""
    F = rng.shape[0]
    for t in prange(n_threads):
        sums[t] = _volume_sum(rng[part(F, t, n_threads):part(F, t + 1, n_threads)])


