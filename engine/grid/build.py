"""build_grid / GridBuilder: validate, compute the grid geometry, then clear, insert and build
macro cells with the chosen strategy, reusing buffers from frame to frame."""

import time
import warnings

import numpy as np

from ..arrays import (TRI_DTYPE, as_origin, as_triangles, float_contiguous, frame_centre, refuse_bad_values,
                      triangle_array)
from ..config import AUTO_STRATEGY, GridParams, resolve_strategy
from ..errors import InputError
from ..precision import ONE_SHOT_SAMPLE, warn_detail
from ..stats import BuildStats
from ..threads import check_threads, concurrent_launches_ok, use_threads
import gridrt.grid.common as common  # (the module: the error tests replace its kernels with tripwires)
from .buffers import GridBuffers, LeafBuffers
from .layout import BOUNDS_PAD, Grid, GridSpec
from .registry import get_builder
from .strategies.base import timed
from .two_level import TwoLevelGrid, build_leaves


class GridCapWarning(UserWarning):
    """The resolution asked for exceeded max_cells and was reduced."""


def grid_dims(extent, n_tris, density, max_cells):
    """Cells per axis for a box of the given extent: about density * n_tris cubical-ish cells.

    Axes too thin for one cell get one and the budget goes to the others (flat scenes).
    Returns (dims (3,) int64, capped bool).
    """
    extent = np.asarray(extent, dtype=np.float64)
    target = max(1.0, density * n_tris)
    capped = target > max_cells
    target = min(target, float(max_cells))
    dims = np.ones(3, np.int64)
    active = [a for a in range(3) if extent[a] > 0]
    for _ in range(3):
        if not active:
            break
        vol = float(np.prod(extent[active]))
        s = (target / vol) ** (1.0 / len(active))
        thin = [a for a in active if extent[a] * s < 1.0]
        if not thin:
            for a in active:
                dims[a] = max(1, int(round(extent[a] * s)))
            break
        for a in thin:
            dims[a] = 1
        active = [a for a in active if a not in thin]
    while int(np.prod(dims)) > max_cells:
        capped = True
        a = int(np.argmax(dims))
        dims[a] = max(1, int(dims[a] * 0.9))
    return dims, capped


def make_spec(lo_scene, hi_scene, n_tris, params):
    """GridSpec over the padded scene bounds, at params.density and params.macro."""
    lo_scene = np.asarray(lo_scene, np.float64)
    hi_scene = np.asarray(hi_scene, np.float64)
    ext = hi_scene - lo_scene
    big = float(ext.max())
    if big > 0:
        pad = BOUNDS_PAD * big
    else:
        pad = max(1e-6 * float(np.abs(lo_scene).max()), 1e-30)
    lo = lo_scene - pad
    hi = hi_scene + pad
    raw_ext = np.where(ext > 1e-9 * max(big, 1e-300), ext, 0.0)
    dims, capped = grid_dims(raw_ext, n_tris, params.density, params.max_cells)
    cell = (hi - lo) / dims
    k = params.macro
    mdims = (dims + k - 1) // k
    return GridSpec(lo=lo, hi=hi, dims=dims, cell=cell, inv_cell=1.0 / cell, macro=k, mdims=mdims, capped=capped,
                    scene_lo=lo_scene, scene_hi=hi_scene)


def _check_tris(tris):
    if not isinstance(tris, np.ndarray) or tris.dtype != TRI_DTYPE or tris.ndim != 3 or tris.shape[1:] != (3, 3):
        return as_triangles(tris)
    if tris.shape[0] == 0:
        raise InputError("triangles: the scene is empty (0 triangles)")
    if not tris.flags.c_contiguous:
        tris = np.ascontiguousarray(tris)
    return tris


class GridBuilder:
    """Builds a grid per frame with fixed parameters, reusing its buffers.

    ``build(tris)`` validates the triangles (shape, dtype, NaN/inf: fused into the bounds pass),
    chooses the resolution from the scene bounds, then runs the strategy's three stages.
    """

    def __init__(self, params: GridParams | None = None):
        self.params = params or GridParams()
        self.bufs = GridBuffers()
        self._auto = None  # grid="auto": (the kind chosen, triangles, builds since it was measured)
        self._stand_ins = 0  # builds by the serial strategy standing in for the parallel default one

    def build(self, tris, params: GridParams | None = None, *, bounds=None) -> Grid:
        """The grid of ``tris`` (F,3,3) float32.  ``bounds``: (lo, hi) of the triangles' corners
        when the caller knows them exactly, values checked (gridrt.RayCaster's update: its
        vertices' bounds); the bounds pass over the triangles is then skipped."""
        if params is not None:
            if params != self.params:
                self._auto = None
            self.params = params
        p = self.params
        threads = check_threads(p.threads)
        t_start = time.perf_counter()
        times = {}
        tris = _check_tris(tris)
        F = tris.shape[0]
        name = resolve_strategy(p.strategy, threads)
        if p.strategy == AUTO_STRATEGY and name != "serial":
            if not _parallel_ready(name, threads, tris, start=self._stand_ins > 0):
                name = "serial"
                self._stand_ins += 1
        strategy = get_builder(name)()
        use_threads(threads)

        with timed(times, "bounds_ms"):
            if bounds is not None:  # the caller's, exact and checked: no pass over the triangles
                bb = np.zeros((1, 7), np.float64)
                bb[0, 0:3], bb[0, 3:6] = bounds
            else:
                # one chunk per thread from a quarter million triangles on (below that, the SIMD
                # pass takes about as long as a parallel launch); serial keeps to one thread throughout
                n_chunks = max(1, min(threads, F // BOUNDS_CHUNK + 1)) if strategy.parallel_stages else 1
                bb = np.empty((n_chunks, 7), np.float64)
                if n_chunks == 1:
                    common.scene_bounds_serial(tris, bb)
                else:
                    common.scene_bounds(tris, n_chunks, bb)
        if bb[:, 6].sum() > 0:
            bad = np.argwhere(~(np.abs(tris) <= common.BAD_MAGNITUDE))[0]
            raise InputError(
                f"triangles contain NaN, infinity or coordinates beyond 1e30 "
                f"(first at triangle {bad[0]}, vertex {bad[1]}, axis {bad[2]})"
            )
        lo_scene = bb[:, 0:3].min(axis=0)
        hi_scene = bb[:, 3:6].max(axis=0)
        kind = p.grid
        if kind == "auto":
            # the choice is measured again every AUTO_RECHECK builds (or when the triangle count
            # changes); in between the chosen kind is built directly (a two-level build measures
            # its crowding anyway, and switches at once when it falls)
            a = self._auto
            if a is not None and a[1] == F and a[2] < AUTO_RECHECK:
                kind = a[0]
                self._auto = (a[0], F, a[2] + 1)
            else:
                self._auto = None
        try:
            if kind == "uniform":
                return self._build(tris, p, strategy, threads, *self._spec(lo_scene, hi_scene, F, p, strategy, threads),
                                   times, t_start)
            # a two-level grid's top level is a uniform grid of top_density with one-cell macro
            # cells (their flags are the top cells' occupancy)
            pt = p.replace(density=p.top_density, macro=1)
            top = self._build(tris, pt, strategy, threads, *self._spec(lo_scene, hi_scene, F, pt, strategy, threads),
                              times, t_start)
            crowd = crowding(top)
            if p.grid == "auto":
                self._auto = ("two_level" if crowd >= AUTO_CROWDING else "uniform", F,
                              self._auto[2] if self._auto is not None else 0)
            if p.grid == "auto" and crowd < AUTO_CROWDING:
                # an even scene: the uniform grid (the top level cost this much more)
                times = {"bounds_ms": times["bounds_ms"],
                         "auto_top_ms": (time.perf_counter() - t_start) * 1e3 - times["bounds_ms"]}
                grid = self._build(tris, p, strategy, threads,
                                   *self._spec(lo_scene, hi_scene, F, p, strategy, threads), times, t_start)
                object.__setattr__(grid.stats, "counters", {**grid.stats.counters, "crowding": crowd})
                return grid
            return self._leaves(top, tris, p, threads, times, t_start, crowd)
        except BaseException:
            # a refused or interrupted build leaves counts the next clear would not know about
            self.bufs = GridBuffers()
            raise

    @staticmethod
    def _spec(lo_scene, hi_scene, F, p, strategy, threads):
        """(spec, layers) of a uniform grid at p's density and macro cells over the scene bounds,
        refused (InputError) when its cell arrays alone exceed p.max_bytes."""
        spec = make_spec(lo_scene, hi_scene, F, p)
        if spec.capped:
            warnings.warn(
                f"grid resolution capped at max_cells={p.max_cells} "
                f"(density {p.density:g} x {F} triangles asked for more); using dims "
                f"{' x '.join(str(int(d)) for d in spec.dims)}",
                GridCapWarning,
                stacklevel=4,
            )
        layers = strategy.layers(threads)
        cell_bytes = layers * (2 * spec.n_cells + 1) * 4
        if cell_bytes > p.max_bytes:
            raise InputError(
                f"{layers} layer(s) of {spec.n_cells} cells need {cell_bytes / 2**20:.0f} MiB, above the memory "
                f"budget max_bytes={p.max_bytes / 2**20:.0f} MiB; lower the density (lambda) or max_cells"
                + (" or the thread count (this strategy keeps one grid per thread)" if layers > 1 else "")
            )
        return spec, layers

    def _build(self, tris, p, strategy, threads, spec, layers, times, t_start):
        F = tris.shape[0]
        bufs = self.bufs
        bufs.generation += 1
        bufs.max_bytes = p.max_bytes

        # clear: only the cells of macro cells that were full in the previous build
        with timed(times, "clear_ms"):
            fresh = bufs.prepare(spec, layers)
            cleared = 0
            if not fresh and bufs.prev_spec is not None:
                prev = bufs.prev_count_view()
                ps = bufs.prev_spec
                if strategy.parallel_stages and threads > 1:
                    touched = np.zeros(threads, np.int64)
                    common.clear_macro_parallel(prev, ps.dims, ps.macro, ps.mdims, bufs.macro_full, threads, touched)
                    cleared = int(touched.sum())
                else:
                    cleared = common.clear_macro_range(prev, ps.dims, ps.macro, ps.mdims, bufs.macro_full, 0, ps.n_macro)
            bufs.set_views(spec, layers)

        with timed(times, "insert_ms"):
            refs = strategy.insert(tris, spec, bufs, threads, p.insert == "exact", times)

        with timed(times, "macro_ms"):
            if strategy.parallel_stages and threads > 1:
                looked = np.zeros(threads, np.int64)
                common.macro_build_parallel(bufs.count, spec.dims, spec.macro, spec.mdims, bufs.macro_full, threads, looked)
                inspected = int(looked.sum())
            else:
                inspected = common.macro_build_range(bufs.count, spec.dims, spec.macro, spec.mdims, bufs.macro_full, 0,
                                                     int(spec.mdims[2]))
        bufs.prev_spec = spec
        bufs.prev_layers = layers

        build_ms = (time.perf_counter() - t_start) * 1e3
        counters = {k: times.pop(k) for k in strategy.counters if k in times}
        grid = Grid(
            spec=spec,
            cell_start=bufs.start,
            tri_ids=bufs.ref_buffer,
            cell_count=bufs.count,
            macro_full=bufs.macro_full,
            references=int(refs),
            n_triangles=F,
            generation=bufs.generation,
            buffers=bufs,
        )
        grid.stats = BuildStats(
            stages=times,
            build_ms=build_ms,
            strategy=strategy.name,
            threads=threads,
            insert=p.insert,
            triangles=F,
            cells=spec.n_cells,
            references=int(refs),
            refs_per_tri=refs / F,
            cells_cleared=cleared,
            cells_inspected=inspected,
            macro_cells=spec.n_macro,
            macro_full=int(bufs.macro_full.sum()),
            dims="x".join(str(int(d)) for d in spec.dims),
            grid_bytes=grid.memory_bytes(),
            counters=counters,
        )
        return grid


    def _leaves(self, top, tris, p, threads, times, t_start, crowd):
        """The two-level grid over the top-level grid ``top`` just built."""
        bufs = self.bufs
        if getattr(bufs, "leaves", None) is None:
            bufs.leaves = LeafBuffers()
        leaf_res, leaf_first, count, start, tri_ids, refs = build_leaves(
            top, tris, p.insert == "exact", p.leaf_density, threads, bufs.leaves, p.max_bytes, times)
        build_ms = (time.perf_counter() - t_start) * 1e3
        st = top.stats
        n_leaf = int(leaf_first[-1])
        grid = TwoLevelGrid(
            spec=top.spec, cell_start=start.reshape(1, -1), tri_ids=tri_ids, cell_count=count.reshape(1, -1),
            macro_full=top.macro_full, references=refs, n_triangles=top.n_triangles, generation=top.generation,
            buffers=bufs, leaf_res=leaf_res, leaf_first=leaf_first, top_start=top.cell_start, top_ids=top.tri_ids,
            top_references=top.references)
        F = top.n_triangles
        grid.stats = BuildStats(
            stages=dict(st.stages), build_ms=build_ms, strategy=st.strategy, threads=st.threads, insert=st.insert,
            triangles=F, cells=n_leaf, references=refs, refs_per_tri=refs / F, cells_cleared=st.cells_cleared,
            cells_inspected=st.cells_inspected, macro_cells=st.cells, macro_full=st.macro_full, dims=st.dims,
            grid_bytes=grid.memory_bytes(),
            counters={**st.counters, "top_references": top.references, "crowding": crowd}, grid="two_level")
        return grid


#: triangles per chunk of the parallel bounds pass (fewer: one chunk, the serial pass)
BOUNDS_CHUNK = 262144
#: triangles of the scene the background warm-up of the parallel default strategy builds
WARM_TRIANGLES = 64

#: parallel default strategies known to be compiled or cached, with the writeability of the
#: triangles (part of their numba type)
_READY = set()
#: those not found in the on-disk cache (its index files are read once, not at every build a
#: serial stand-in makes)
_COLD = set()


def _parallel_ready(name, threads, tris, start):
    """Whether GridParams(strategy="auto") at ``threads`` > 1 builds with its parallel default
    strategy ``name`` (True) or with the serial strategy standing in for it (False), which builds
    the same grid (the same cells, each list in the same order) and compiles seconds faster on a
    cold numba cache (BENCHMARKS.md section 10).

    Its kernels compiled in this process or found in the on-disk cache: yes.  Otherwise the
    serial strategy builds; with ``start`` (the builder's second build by the serial strategy, so
    that a one-frame run never starts it) a background thread warms the parallel one up
    (gridrt.trace.twin.Twins.warm: listed by ``TWINS.compiling()``, waited for by a dump at exit)
    by building a few of the scene's triangles with it, twice (the second build runs the clear
    stage); every build after that uses it.  Under parallel_first (benchmarks): yes.  With a
    threading layer that must not run parallel kernels from two threads at once (numba's
    workqueue, without libgomp): yes, as the warm-up would run beside the frames' kernels."""
    from ..trace.twin import TWINS, has_cache_entry  # deferred: gridrt.trace imports gridrt.grid

    key = (name, bool(tris.flags.writeable))
    if key in _READY:
        return True
    if not concurrent_launches_ok():
        _READY.add(key)
        return True
    kernels = (*get_builder(name).parallel_kernels, common.clear_macro_parallel, common.macro_build_parallel)
    if not all(hasattr(k, "signatures") for k in kernels):  # (one replaced by a plain function)
        return True
    if all(k.signatures or (key not in _COLD and has_cache_entry(k)) for k in kernels):
        _READY.add(key)
        return True
    _COLD.add(key)

    def job():
        # the default parameters: the kernels' types do not depend on them, and a memory budget,
        # density or grid kind of the user's own could refuse a grid of a few triangles
        sample = tris[:WARM_TRIANGLES].copy()
        sample.setflags(write=tris.flags.writeable)
        builder = GridBuilder(GridParams(strategy=name, threads=threads))
        builder.build(sample)
        builder.build(sample)
        if tris.shape[0] >= BOUNDS_CHUNK:
            common.scene_bounds(sample, threads, np.empty((threads, 7)))

    if TWINS.warm(("build", *key), f"{name} build", job, start):
        _READY.add(key)
        return True
    return False


#: GridParams(grid="auto") builds a two-level grid when the top level's crowding (:func:`crowding`)
#: is at least this, a uniform grid otherwise (BENCHMARKS.md section 14)
AUTO_CROWDING = 4.0
#: GridParams(grid="auto") measures the crowding again after this many builds of a uniform grid
AUTO_RECHECK = 30


def crowding(top):
    """How unevenly the triangles of a scene fill a coarse grid ``top`` (a two-level grid's top
    level): the mean references of the cell a reference lies in (sum n^2 / sum n over the cells'
    reference counts n) over the mean references of a non-empty cell (sum n / non-empty cells).
    1 when every non-empty cell holds as many; large when most triangles crowd into a few cells
    (an interior with detailed objects, small objects in a large volume)."""
    n = np.diff(top.cell_start, axis=1).sum(axis=0).astype(np.float64)
    total = n.sum()
    if total == 0:
        return 1.0
    return float((n * n).sum() / total / (total / np.count_nonzero(n)))


def build_grid(tris, params: GridParams | None = None, *, origin=None, **kw) -> Grid:
    """One-shot build. ``kw`` are GridParams fields (e.g. strategy="serial", density=4).

    ``tris`` (F,3,3) float64 or float32 world coordinates.  The grid is built in the frame of
    ``origin`` (3 floats, stored as ``grid.origin``): by default the centre of the triangles'
    bounds when they lie farther from the world origin than their own extent, else 0.  Pass the
    origin of another grid to build grids that are traversed together (``Renderer.render(second=)``).
    """
    if params is None:
        params = GridParams(**kw)
    elif kw:
        params = params.replace(**kw)
    # one pass over the values for bounds and NaN/inf/1e30 (the messages come from the slow checks,
    # run only when the pass found something) that also stores float32, and a second one to move
    # them into a frame centred on the scene only when it lies far away
    a = float_contiguous(triangle_array(tris))
    as32 = a if a.dtype == np.float32 else np.empty(a.shape, np.float32)  # (the builder only reads it)
    lo, hi, bad = common.point_bounds(a, None if as32 is a else as32)
    if bad:
        refuse_bad_values(a)
    # a scene far from the world origin is gridded in a frame centred on it (grid.origin), from its
    # float64 coordinates, so float32 keeps the precision of the scene's own size
    origin = frame_centre(0.5 * (lo + hi), float((hi - lo).max())) if origin is None else as_origin(origin)
    if not origin.any():
        local = as32
    else:
        local = np.empty(a.shape, np.float32)
        common.to_frame(a.reshape(-1, 3), float(origin[0]), float(origin[1]), float(origin[2]), local.reshape(-1, 3))
    if common.first_nondegenerate(local) < 0:
        raise InputError(f"triangles: all {len(local)} triangles are degenerate (zero area)")
    warn_detail(local, "the triangles", big=float(max(np.abs(lo - origin).max(), np.abs(hi - origin).max())),
                sample=ONE_SHOT_SAMPLE)
    grid = GridBuilder(params).build(local)  # the builder is dropped: the grid owns its buffers
    grid.origin = origin
    return grid
