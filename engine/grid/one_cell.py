"""OneCellBuilder: a grid builder that runs no numba kernel.

Every grid it returns has one cell, over the padded bounds of the triangles, holding all of them
(a two-level grid: one top cell holding one leaf cell that holds them all).  That is a real grid:
a ray cast through it tests every triangle and finds the hits a brute-force caster finds.  Its
arrays have the dtypes, dimensions and layouts of :class:`gridrt.grid.build.GridBuilder`'s, so
the ray casting kernels see the numba types of a built grid of that kind: what a process that
compiles the ray casting of a frame without compiling its grid build needs
(:mod:`gridrt.coldstart`).  It is made with NumPy in time linear in the triangles and is no
substitute for a built grid when rays are many: each ray tests every triangle.
"""

import numpy as np

from ..config import GridParams
from ..errors import InputError
from ..stats import BuildStats
from .build import make_spec
from .layout import Grid, GridSpec
from .two_level import TwoLevelGrid


class OneCellBuilder:
    """``build(tris, params)`` as :meth:`GridBuilder.build` takes it; the grid kind is
    ``params.grid`` ("auto" gives a uniform grid)."""

    def __init__(self, params: GridParams | None = None):
        self.params = params or GridParams()

    def build(self, tris, params: GridParams | None = None):
        if params is not None:
            self.params = params
        p = self.params
        tris = np.ascontiguousarray(tris, np.float32)
        if tris.ndim != 3 or tris.shape[1:] != (3, 3) or tris.shape[0] == 0:
            raise InputError(f"triangles must be a non-empty (F, 3, 3) array, got shape {tris.shape}")
        F = tris.shape[0]
        flat = tris.reshape(-1, 3).astype(np.float64)
        lo_scene, hi_scene = flat.min(axis=0), flat.max(axis=0)
        if not (np.isfinite(lo_scene).all() and np.isfinite(hi_scene).all()):
            raise InputError("triangles contain NaN or infinite coordinates")
        padded = make_spec(lo_scene, hi_scene, F, p)  # the bounds GridBuilder's grid has (its cells aside)
        lo, hi = padded.lo, padded.hi
        one = np.ones(3, np.int64)
        cell = hi - lo
        spec = GridSpec(lo=lo, hi=hi, dims=one, cell=cell, inv_cell=1.0 / cell, macro=1 if p.grid == "two_level"
                        else p.macro, mdims=one.copy(), scene_lo=lo_scene, scene_hi=hi_scene)
        ids = np.arange(F, dtype=np.int32)
        start = np.array([[0, F]], np.int32)
        count = np.array([[F]], np.int32)
        full = np.ones(1, np.uint8)
        kw = dict(spec=spec, cell_start=start, tri_ids=ids, cell_count=count, macro_full=full, references=F,
                  n_triangles=F)
        if p.grid == "two_level":
            grid = TwoLevelGrid(leaf_res=np.ones((1, 3), np.int32), leaf_first=np.array([0, 1], np.int32),
                                top_start=start.copy(), top_ids=ids.copy(), top_references=F, **kw)
        else:
            grid = Grid(**kw)
        grid.stats = BuildStats(stages={}, build_ms=0.0, strategy="one_cell", threads=1, insert=p.insert,
                                triangles=F, cells=1, references=F, refs_per_tri=1.0, cells_cleared=0,
                                cells_inspected=0, macro_cells=1, macro_full=1, dims="1x1x1",
                                grid_bytes=grid.memory_bytes(), grid=grid.kind)
        return grid
