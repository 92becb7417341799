"""Data layout of the uniform grid (the structure every build strategy fills).

A grid covers the padded bounding box of the scene with ``nx * ny * nz`` cells of equal size.
Cell ``(i, j, k)`` has the linear index ``c = i + nx * (j + ny * k)``; ``k`` (z) is the major
index, the one the sort-first and sort-middle strategies split the grid on.

The cell lists are stored compactly (CSR): the triangles of cell ``c`` in layer ``l`` are
``tri_ids[cell_start[l, c] : cell_start[l, c + 1]]``.  Every strategy except ``thread_grids``
produces one layer; ``thread_grids`` keeps one layer per thread and the ray caster visits them
all.  Macro cells are blocks of ``k**3`` cells (fewer at the upper edges) with one flag each:
non-empty or empty, so traversal can skip empty space (Parker et al. 1999; Wald et al. 2006).

Membership rule (what "the same grid contents" means for every strategy and the tests):
a triangle is in a cell when its axis-aligned bounding box, grown by ``INSERT_EPS`` cell sizes
on every side, overlaps the closed cell box.  Triangles of exactly zero area (float64 cross
product of their float32 edges exactly zero) are in no cell: they cannot be hit.  With exact insertion the triangle must also not be
separated from the grown cell box by any of the 13 separating axes (Akenine-Möller 2001).
The growth makes insertion conservative, so a ray that hits a triangle exactly on a cell face
still finds it in the cell whose t-range contains the hit.
"""

from collections import namedtuple
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import InputError

#: Growth of each triangle's bounding box, in cell sizes, before it is binned (see module doc).
INSERT_EPS = 1e-5
#: Relative padding of the scene bounds, so every vertex lies strictly inside the grid.
BOUNDS_PAD = 1e-4

#: A grid's box and resolution as every build kernel takes it (:attr:`GridSpec.box`): lo, cell,
#: inv_cell (3,) float64 C-contiguous; dims, mdims (3,) int64 C-contiguous; macro int.
GridBox = namedtuple("GridBox", "lo cell inv_cell dims macro mdims")


@dataclass(frozen=True)
class GridSpec:
    """Geometry of a grid: where it is, how many cells, how big.

    lo, hi     (3,) float64  grid bounds (the scene's bounds padded by BOUNDS_PAD)
    dims       (3,) int64    cells along x, y, z (nx, ny, nz), each >= 1
    cell       (3,) float64  cell size along each axis, (hi - lo) / dims
    inv_cell   (3,) float64  1 / cell
    macro      int           macro-cell edge k, in cells
    mdims      (3,) int64    macro cells along each axis, ceil(dims / k)
    capped     bool          True when the resolution asked for was reduced to max_cells
    scene_lo, scene_hi (3,) float64  the triangles' own bounds (unpadded)
    """

    lo: np.ndarray
    hi: np.ndarray
    dims: np.ndarray
    cell: np.ndarray
    inv_cell: np.ndarray
    macro: int
    mdims: np.ndarray
    capped: bool = False
    scene_lo: np.ndarray = None
    scene_hi: np.ndarray = None

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.dims))

    @property
    def n_macro(self) -> int:
        return int(np.prod(self.mdims))

    @cached_property
    def box(self) -> GridBox:
        """The geometry as the build kernels take it, in their fixed dtypes."""
        f64 = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
        i64 = lambda a: np.ascontiguousarray(a, np.int64)  # noqa: E731
        return GridBox(f64(self.lo), f64(self.cell), f64(self.inv_cell), i64(self.dims), int(self.macro),
                       i64(self.mdims))


@dataclass
class Grid:
    """A built grid: spec, cell lists, macro-cell flags and the build's statistics.

    spec        GridSpec
    cell_start  (L, C + 1) int32  CSR offsets into tri_ids per layer; C = spec.n_cells
    tri_ids     (R_cap,) int32    triangle ids; the first ``references`` entries are used
    cell_count  (L, C) int32      triangles per cell per layer (what the next clear resets)
    macro_full  (M,) uint8        1 when any cell of the macro cell is non-empty; M = spec.n_macro
    references  int               total (cell, triangle) references over all layers
    n_triangles int               triangles the grid was built over
    stats       BuildStats        the build's stage timings in ms (bounds, clear, insert and the
                                  strategy's own parts of it, macro) and its counts
                                  (gridrt.stats; reads like a dict by column name too)
    generation  int               which build of ``buffers`` this grid is
    origin      (3,) float64      world position of the grid's coordinate origin: the grid and
                                  the triangles it was built over live in ``world - origin``
                                  (:func:`build_grid` centres a scene far from the world origin;
                                  render and cast_rays take world inputs and move them)

    The arrays are views of its GridBuilder's buffers, which the builder's next build reuses:
    a grid is valid until then (:meth:`check_current` raises afterwards).  A grid from
    ``build_grid`` owns its buffers.
    """

    spec: GridSpec
    cell_start: np.ndarray
    tri_ids: np.ndarray
    cell_count: np.ndarray
    macro_full: np.ndarray
    references: int
    n_triangles: int
    stats: dict = field(default_factory=dict)
    generation: int = 0
    buffers: object = field(default=None, repr=False)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))

    #: "uniform"; a two-level grid (gridrt.grid.two_level.TwoLevelGrid) says "two_level"
    kind = "uniform"

    def check_current(self):
        """Raise InputError when the builder that made this grid has built another since."""
        if self.buffers is not None and self.buffers.generation != self.generation:
            raise InputError(
                "this grid is stale: its GridBuilder has built another grid since, reusing its buffers "
                "(use the newest grid, or build_grid() for a grid that owns its arrays)"
            )

    @property
    def layers(self) -> int:
        return self.cell_start.shape[0]

    def cell_tris(self, c):
        """Sorted triangle ids of cell ``c`` (union over layers), int32 array."""
        parts = [self.tri_ids[self.cell_start[l, c] : self.cell_start[l, c + 1]] for l in range(self.layers)]
        return np.sort(np.concatenate(parts)).astype(np.int32)

    def pairs(self):
        """All (cell, triangle) pairs as a sorted, duplicate-free (P, 2) int64 array."""
        out = []
        C = self.spec.n_cells
        for l in range(self.layers):
            start = self.cell_start[l].astype(np.int64)
            counts = np.diff(start)
            cells = np.repeat(np.arange(C, dtype=np.int64), counts)
            tris = self.tri_ids[start[0] : start[-1]].astype(np.int64)
            out.append(np.stack([cells, tris], axis=1))
        p = np.concatenate(out) if out else np.zeros((0, 2), np.int64)
        return np.unique(p, axis=0)

    def memory_bytes(self) -> int:
        """Bytes held by the grid's arrays (capacity, not just what is used)."""
        return int(self.cell_start.nbytes + self.tri_ids.nbytes + self.cell_count.nbytes + self.macro_full.nbytes)
