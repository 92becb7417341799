"""Sort-last with one shared grid guarded by mutexes: ``global_lock``, ``cell_locks``, ``lock_pool``.

Ize, Wald, Robertson, Parker, "An Evaluation of Parallel Grid Construction for Ray Tracing
Dynamic Scenes", RT 2006, "Sort-last: global grid": each thread takes a subset of the
triangles (here the t-th contiguous block) and inserts them into the one grid, taking a mutex
around every cell update.  The paper's three mutex granularities:

* ``global_lock``: "single mutex for the entire grid" (degenerates into a serial build, and is
  expected to be slower than serial because of the lock traffic);
* ``cell_locks``: "mutex for every cell" (a (C,) int32 lock array: almost no contention, but
  memory and lock overhead on every reference);
* ``lock_pool``: "mutex per macro cell" (a (M,) int32 lock array, one per macro cell).

The grid is compact (CSR), so insertion is count -> prefix sum -> scatter, and both passes
take the lock: the count pass around ``count[c] += 1``, the scatter around claiming a slot
(``p = start[c] - 1; start[c] = p``); the triangle id is written after the unlock, into a slot
no other thread owns.  Both passes read the triangles' cell ranges from a parallel pre-pass
(:func:`shared.cell_ranges`).  The locks are the compare-and-swap spin locks of
:mod:`gridrt.grid.atomics`.  ``insert`` adds ``lock_waits`` (failed looks at a held lock, summed
over threads and both passes) to the stage times: the contention figure.  Cell lists come out in
no particular order.
"""

import numpy as np
from numba import njit, prange

from ...compiles import inner
from ..atomics import spin_lock, spin_unlock
from ..buffers import scratch
from ..common import cell_overlaps
from .base import Strategy, timed
from .shared import parallel_scan, part, ranges

#: lock granularity codes passed to the kernels
GLOBAL, PER_CELL, PER_MACRO = 0, 1, 2


@inner(cache=True)
def _lock_id(kind, c, i, j, k, macro, mdims):
    if kind == PER_CELL:
        return c
    if kind == PER_MACRO:
        return i // macro + mdims[0] * (j // macro + mdims[1] * (k // macro))
    return 0


@njit(cache=True, parallel=True)
def count_locked(tris, rng, box, exact, n_threads, kind, locks, count, waits):
    """count[c] += 1 under lock ``_lock_id(kind, c, ...)``; thread t takes its triangle block.

    rng (F, 6) int32 cell ranges; count (C,) int32 zero on entry; locks int32 all zero (free);
    waits (T,) int64 receives each thread's failed lock looks; box the grid (layout.GridBox).
    """
    lo, cell, dims, macro, mdims = box.lo, box.cell, box.dims, box.macro, box.mdims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for t in prange(n_threads):
        w = 0
        for f in range(part(F, t, n_threads), part(F, t + 1, n_threads)):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        c = base + i
                        lk = _lock_id(kind, c, i, j, k, macro, mdims)
                        w += spin_lock(locks, lk)
                        count[c] += 1
                        spin_unlock(locks, lk)
        waits[t] = w


@njit(cache=True, parallel=True)
def scatter_locked(tris, rng, box, exact, n_threads, kind, locks, start, tri_ids, waits):
    """Claim slot ``start[c] - 1`` under the lock and write the triangle id there.

    start (C+1,) int32 inclusive ends on entry, CSR starts on exit; tri_ids (R,) int32;
    waits (T,) int64 gets each thread's failed lock looks added.
    """
    lo, cell, dims, macro, mdims = box.lo, box.cell, box.dims, box.macro, box.mdims
    F = tris.shape[0]
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for t in prange(n_threads):
        w = 0
        for f in range(part(F, t, n_threads), part(F, t + 1, n_threads)):
            i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
            for k in range(k0, k1 + 1):
                for j in range(j0, j1 + 1):
                    base = k * nxy + j * nx
                    for i in range(i0, i1 + 1):
                        if exact and not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                        c = base + i
                        lk = _lock_id(kind, c, i, j, k, macro, mdims)
                        w += spin_lock(locks, lk)
                        p = start[c] - 1
                        start[c] = p
                        spin_unlock(locks, lk)
                        tri_ids[p] = f
        waits[t] += w


class _SortLastLocked(Strategy):
    """Shared body of the three mutex strategies; subclasses set ``kind``."""

    kind = GLOBAL
    counters = ("lock_waits",)

    def n_locks(self, spec):
        return {GLOBAL: 1, PER_CELL: spec.n_cells, PER_MACRO: spec.n_macro}[self.kind]

    def insert(self, tris, spec, bufs, threads, exact, times):
        count = bufs.count[0]
        start = bufs.start[0]
        # every unlock stores 0, so the lock array is all free between builds
        locks = scratch(bufs, "locks", self.n_locks(spec), np.int32)
        waits = np.zeros(threads, np.int64)
        rng = ranges(tris, spec, bufs, threads, times)
        args = (tris, rng, spec.box, exact, threads, self.kind, locks)
        with timed(times, "count_ms"):
            count_locked(*args, count, waits)
        with timed(times, "scan_ms"):
            refs = parallel_scan(count, start, threads)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_locked(*args, start, tri_ids, waits)
        times["lock_waits"] = times.get("lock_waits", 0) + int(waits.sum())
        return refs


class GlobalLock(_SortLastLocked):
    """Sort-last, one shared grid, a single mutex for the whole grid."""

    name = "global_lock"
    kind = GLOBAL


class CellLocks(_SortLastLocked):
    """Sort-last, one shared grid, one mutex per cell."""

    name = "cell_locks"
    kind = PER_CELL


class LockPool(_SortLastLocked):
    """Sort-last, one shared grid, one mutex per macro cell."""

    name = "lock_pool"
    kind = PER_MACRO
