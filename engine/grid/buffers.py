"""The arrays a GridBuilder keeps from one build to the next: the grid's cell and reference
buffers (:class:`GridBuffers`), a two-level grid's leaf level (:class:`LeafBuffers`) and the
strategies' scratch arrays kept alongside them; each grows only when it must, by :func:`grown`."""

import weakref

import numpy as np

from ..errors import InputError
from ..memory import check_fits

INT32_MAX = np.iinfo(np.int32).max


def grown(n, factor):
    """The size an array of buffers kept from build to build is given when ``n`` elements do not
    fit: ``factor`` times more (room for the next frames) and 16."""
    return int(n * factor) + 16


#: growth of the cell arrays (and the strategies' scratch arrays) and of the references
CELL_GROWTH, REF_GROWTH = 1.25, 1.5


def build_bytes(cells, references, triangles, layers=1):
    """Bytes a fresh GridBuilder allocates to build a uniform grid of ``cells`` cells (in
    ``layers`` layers) holding ``references`` over ``triangles`` triangles: the int32 counts and
    offsets (:meth:`GridBuffers.prepare`), the int32 references (:meth:`GridBuffers.refs`) and
    the int32 cell ranges, six a triangle (gridrt.grid.strategies.shared.ranges), each grown
    (:func:`grown`).  Each is checked against the memory left (gridrt.memory) before it is
    allocated."""
    return 4 * (grown(layers * cells, CELL_GROWTH) + grown(layers * (cells + 1), CELL_GROWTH)
                + grown(references, REF_GROWTH) + grown(6 * triangles, CELL_GROWTH))


class GridBuffers:
    """Arrays kept from one build to the next; they grow only when they must.

    count  (L, C) int32 view into a flat buffer; all zero between clear and insert
    start  (L, C+1) int32 view
    refs(n) -> (n,) int32 view of the reference buffer (grown by 1.5x when too small)
    """

    def __init__(self):
        self._count = np.zeros(0, np.int32)
        self._start = np.zeros(0, np.int32)
        self._refs = np.zeros(0, np.int32)
        self.macro_full = np.zeros(0, np.uint8)
        self.count = self._count.reshape(0, 0)
        self.start = self._start.reshape(0, 1)
        self.prev_spec = None  # spec and layers of the last build, for the next clear
        self.prev_layers = 0
        self.generation = 0  # bumped by every build: grids of older builds are stale
        self.max_bytes = None  # memory budget of the build in progress (GridParams.max_bytes)

    def prepare(self, spec, layers):
        """Size the views for this build. Returns True when count is known to be all zero."""
        C = spec.n_cells
        fresh = False
        new = [grown(n, CELL_GROWTH) if have < n else 0
               for have, n in ((self._count.size, layers * C), (self._start.size, layers * (C + 1)))]
        check_fits(4 * sum(new), f"a grid of {layers * C:,} cells", "int32 counts and offsets",
                   "lower the density (lambda) or max_cells")
        if new[0]:
            self._count = np.zeros(new[0], np.int32)
            fresh = True
        if new[1]:
            self._start = np.zeros(new[1], np.int32)
        return fresh

    def set_views(self, spec, layers):
        C = spec.n_cells
        self.count = self._count[: layers * C].reshape(layers, C)
        self.start = self._start[: layers * (C + 1)].reshape(layers, C + 1)
        M = spec.n_macro
        if self.macro_full.size != M:
            self.macro_full = np.zeros(M, np.uint8)

    def prev_count_view(self):
        s = self.prev_spec
        C = s.n_cells
        return self._count[: self.prev_layers * C].reshape(self.prev_layers, C)

    def check_budget(self, extra, what):
        """InputError when the cell arrays plus ``extra`` bytes exceed the build's max_bytes."""
        if self.max_bytes is None:
            return
        need = extra + self.count.nbytes + self.start.nbytes
        if need > self.max_bytes:
            raise InputError(
                f"the grid would need {need / 2**20:.0f} MiB ({what}), above the memory budget "
                f"max_bytes={self.max_bytes / 2**20:.0f} MiB; lower the density (lambda), use exact insertion, "
                f"fewer threads or raise max_bytes"
            )

    def refs(self, n):
        if n > INT32_MAX:
            raise InputError(
                f"the grid would hold {n} references, more than int32 offsets allow; lower the density "
                f"(lambda) or use exact insertion"
            )
        if self.max_bytes is not None:
            need = 4 * n + self.count.nbytes + self.start.nbytes
            if need > self.max_bytes:
                raise InputError(
                    f"the grid would need {need / 2**20:.0f} MiB ({n} references over {self.count.size} cells), "
                    f"above the memory budget max_bytes={self.max_bytes / 2**20:.0f} MiB; lower the density "
                    f"(lambda), use exact insertion or raise max_bytes"
                )
        if self._refs.size < n:
            check_fits(4 * grown(n, REF_GROWTH), f"a grid of {n:,} references", "int32 triangle ids of its cells",
                       "lower the density (lambda) or use exact insertion")
            self._refs = np.empty(grown(n, REF_GROWTH), np.int32)
        return self._refs[:n]

    @property
    def ref_buffer(self):
        return self._refs


class LeafBuffers:
    """The leaf level's arrays, kept from one build to the next; they grow only when they must."""

    def __init__(self):
        self.res = np.zeros((0, 3), np.int32)
        self.first = np.zeros(1, np.int32)
        self._count = np.zeros(0, np.int32)
        self._start = np.zeros(1, np.int32)
        self._refs = np.zeros(0, np.int32)

    def leaf_arrays(self, n_leaf):
        new = [grown(n, CELL_GROWTH) if have < n else 0 for have, n in ((self._count.size, n_leaf),
                                                                         (self._start.size, n_leaf + 1))]
        check_fits(4 * sum(new), f"a two-level grid of {n_leaf:,} leaf cells", "int32 counts and offsets",
                   "lower the leaf or top density")
        if new[0]:
            self._count = np.zeros(new[0], np.int32)
        if new[1]:
            self._start = np.zeros(new[1], np.int32)
        start = self._start[: n_leaf + 1]
        start[0] = 0
        return self._count[:n_leaf], start

    def refs(self, n):
        if self._refs.size < n:
            check_fits(4 * grown(n, REF_GROWTH), f"a two-level grid of {n:,} leaf references",
                       "int32 triangle ids of its leaf cells", "lower the leaf or top density or use exact insertion")
            self._refs = np.empty(grown(n, REF_GROWTH), np.int32)
        return self._refs[:n]


# ---------------------------------------------------------------------------------------------
# scratch arrays kept per GridBuffers (so a GridBuilder reuses them frame to frame)

_SCRATCH = weakref.WeakKeyDictionary()


def scratch(bufs, name, n, dtype):
    """A reusable (n,) array of ``dtype`` held alongside ``bufs``; contents are whatever the
    previous user left, except that a newly allocated array is zero.  Grows by 1.25x."""
    store = _SCRATCH.setdefault(bufs, {})
    a = store.get(name)
    if a is None or a.size < n or a.dtype != np.dtype(dtype):
        check_fits(np.dtype(dtype).itemsize * grown(n, CELL_GROWTH), f"a grid build's {n:,} scratch values ({name})",
                   "kept for later frames", "lower the density (lambda), max_cells or the thread count")
        a = np.zeros(grown(n, CELL_GROWTH), dtype)
        store[name] = a
    return a[:n]


def zero_scratch(bufs, name, n, dtype):
    """Like :func:`scratch` for an array that users keep all zero between builds (they zero
    what they wrote when they consume it).  Call :func:`scratch_done` once it is zero again;
    a build that stopped half-way leaves it marked dirty and the next call zeroes it."""
    store = _SCRATCH.setdefault(bufs, {})
    a = scratch(bufs, name, n, dtype)
    if store.get(name + "/dirty", False):
        store[name].fill(0)
    store[name + "/dirty"] = True
    return a


def scratch_done(bufs, name):
    """Mark a :func:`zero_scratch` array as all zero again."""
    _SCRATCH.setdefault(bufs, {})[name + "/dirty"] = False
