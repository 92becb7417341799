"""``serial``: the single-threaded rebuild of Ize et al. 2006 ("Serial grid rebuild").

The clear and macro-cell stages are the shared ones in :mod:`gridrt.grid.common` (clear only
cells of macro cells that were full last frame; flag a macro cell at its first non-empty cell).
Insertion puts each triangle into every cell its bounding box overlaps (or, with exact
insertion, every such cell the separating-axis test keeps).  Cells are stored compactly, so
insertion runs as count -> prefix sum -> scatter over each triangle's cell range, computed once
per build; the scatter walks triangles backwards and fills each cell from its end, which leaves
every cell's list in ascending triangle order.
"""

from numba import njit

from ..common import cell_overlaps, scan_inclusive
from .base import Strategy, timed
from .shared import ranges


@njit(cache=True)
def count_serial(rng, tris, box, exact, count):
    """count[c] += 1 for every (cell, triangle) reference; count (C,) int32 starts at zero.

    rng (F, 6) int32: each triangle's inclusive cell range (shared.cell_ranges); exact: True for
    exact insertion (the triangle-box test per cell), None for bounding-box insertion; box the grid
    (layout.GridBox)."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for f in range(rng.shape[0]):
        i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
        for k in range(k0, k1 + 1):
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact is not None:  # None: bbox insertion, and numba compiles no overlap test
                        if not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                    count[base + i] += 1


@njit(cache=True)
def scatter_serial(rng, tris, box, exact, start, tri_ids):
    """Write every reference; start holds inclusive ends on entry and CSR starts on exit."""
    lo, cell, dims = box.lo, box.cell, box.dims
    nx = dims[0]
    nxy = dims[0] * dims[1]
    for f in range(rng.shape[0] - 1, -1, -1):
        i0, j0, k0, i1, j1, k1 = rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3], rng[f, 4], rng[f, 5]
        for k in range(k0, k1 + 1):
            for j in range(j0, j1 + 1):
                base = k * nxy + j * nx
                for i in range(i0, i1 + 1):
                    if exact is not None:  # (as count_serial)
                        if not cell_overlaps(tris, f, i, j, k, lo, cell):
                            continue
                    c = base + i
                    p = start[c] - 1
                    start[c] = p
                    tri_ids[p] = f


class Serial(Strategy):
    """One thread: clear, insert (ranges, count, scan, scatter), macro build."""

    name = "serial"
    parallel_stages = False

    def insert(self, tris, spec, bufs, threads, exact, times):
        count = bufs.count[0]
        start = bufs.start[0]
        rng = ranges(tris, spec, bufs, 1, times)
        with timed(times, "count_ms"):
            count_serial(rng, tris, spec.box, True if exact else None, count)
        with timed(times, "scan_ms"):
            refs = scan_inclusive(count, start)
        tri_ids = bufs.refs(refs)
        with timed(times, "scatter_ms"):
            scatter_serial(rng, tris, spec.box, True if exact else None, start, tri_ids)
        return refs
